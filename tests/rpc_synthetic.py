"""Synthetic RPC models for the RPC tests (no shared data): ``coeffs`` names the 20 RPC00B terms, ``model`` builds a
model over a ~0.04 degree square near Ventoux with the terrain at ``H0`` m (ellipsoidal)."""

from riverbed_cli.geometry.rpc import RPCModel

H0 = 500.0  # the terrain (m, ellipsoidal)
TERMS = ["1", "L", "P", "H", "LP", "LH", "PH", "LL", "PP", "HH", "PLH", "LLL", "LPP", "LHH", "LLP", "PPP", "PHH", "LLH",
         "PPH", "HHH"]


def coeffs(**terms):
    """20 RPC00B coefficients from named terms (order of rpc.RPC_TERMS)."""
    out = [0.0] * 20
    for k, v in terms.items():
        out[TERMS.index(k)] = v
    return out


def model(samp, line, samp_off=120.0, line_off=120.0):
    """A model with the given column (``samp``) and row (``line``) numerators and unit denominators."""
    return RPCModel.from_dict({
        "LINE_OFF": line_off, "SAMP_OFF": samp_off, "LAT_OFF": 44.2, "LONG_OFF": 5.2, "HEIGHT_OFF": H0,
        "LINE_SCALE": 2000.0, "SAMP_SCALE": 2000.0, "LAT_SCALE": 0.02, "LONG_SCALE": 0.02, "HEIGHT_SCALE": 500.0,
        "LINE_NUM_COEFF": line, "LINE_DEN_COEFF": coeffs(**{"1": 1.0}), "SAMP_NUM_COEFF": samp,
        "SAMP_DEN_COEFF": coeffs(**{"1": 1.0})}, source="synthetic")
