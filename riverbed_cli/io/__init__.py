"""Reading and writing files: images, disparity maps, and the atomic-output helper."""
