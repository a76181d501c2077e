"""Names of the UFF58 codes an import message quotes (record 6's function type, records 8-11's specific data
type), so a refusal says what a record is -- "a power spectral density (PSD)" -- rather than a bare number."""
from __future__ import annotations

FUNCTION_TYPES = {
    0: "a general function", 1: "a time response", 2: "an auto spectrum", 3: "a cross spectrum",
    4: "a frequency response function (FRF)", 5: "a transmissibility", 6: "a coherence",
    7: "an auto correlation", 8: "a cross correlation", 9: "a power spectral density (PSD)",
    10: "an energy spectral density (ESD)", 11: "a probability density function", 12: "a spectrum",
    13: "a cumulative frequency distribution", 14: "a peaks/valley function", 15: "a stress/cycles function",
    16: "a strain/cycles function", 17: "an orbit", 18: "a mode indicator function", 19: "a force pattern",
    20: "a partial power", 21: "a partial coherence", 22: "an eigenvalue", 23: "an eigenvector",
    24: "a shock response spectrum", 25: "a finite impulse response filter", 26: "a multiple coherence",
    27: "an order function",
}

DATA_TYPES = {
    0: "unknown", 1: "general", 2: "stress", 3: "strain", 5: "temperature", 6: "heat flux", 8: "displacement",
    9: "reaction force", 11: "velocity", 12: "acceleration", 13: "excitation force", 15: "pressure",
    16: "mass", 17: "time", 18: "frequency", 19: "rpm", 20: "order", 21: "sound pressure",
    22: "sound intensity", 23: "sound power",
}


def function_name(code: int) -> str:
    """``9`` -> ``a power spectral density (PSD)``."""
    return FUNCTION_TYPES.get(int(code), f"a function of type {code}, not a standard UFF58 type")


def data_type_name(code: int) -> str:
    """``21`` -> ``sound pressure``."""
    return DATA_TYPES.get(int(code), "not a standard type")
