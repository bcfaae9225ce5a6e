"""Products made from disparity maps: evaluation against ground truth and visualisations (later: DSMs)."""
