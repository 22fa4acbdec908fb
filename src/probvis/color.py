"""Luminance of linear RGB (Rec. 709 / sRGB primaries, as Mitsuba's RGB variants): what emitters are chosen by
and what efficiency-aware estimators weigh a segment's contribution by."""
import numpy as np
from numba import njit

LUMINANCE = np.array([0.212671, 0.715160, 0.072169])


@njit(cache=True, error_model="numpy", inline="always")
def luminance(r, g, b):
    """The luminance of one linear RGB value."""
    return 0.212671 * r + 0.715160 * g + 0.072169 * b
