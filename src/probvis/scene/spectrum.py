"""Sampled spectra (`<spectrum value="400:0.2, 500:0.8, ..."/>`) reduced to linear sRGB as Mitsuba 3's RGB
variants reduce them: the piecewise-linear spectrum (zero outside its wavelengths) integrated against the CIE
1931 colour-matching functions over 360-830 nm in 1000 steps, under D65 for reflectances (normalised so that
a flat spectrum of 1 is white) and directly for emission (normalised by the integral of y-bar), then
XYZ -> sRGB; reflectances are clamped to [0, 1]. The CIE tables come from colour-science.
"""
from functools import lru_cache

import numpy as np

CIE_MIN, CIE_MAX, STEPS = 360.0, 830.0, 1000
XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                        [-0.969256, 1.875991, 0.041556],
                        [0.055648, -0.204043, 1.057311]])


@lru_cache(maxsize=1)
def _tables():
    """The sample wavelengths, the CIE 1931 2-degree colour-matching functions and D65 there."""
    import colour

    x = CIE_MIN + np.arange(STEPS) / (STEPS - 1) * (CIE_MAX - CIE_MIN)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    d65 = colour.SDS_ILLUMINANTS["D65"]
    xyz = np.column_stack([np.interp(x, cmfs.wavelengths, cmfs.values[:, k]) for k in range(3)])
    return x, xyz, np.interp(x, d65.wavelengths, d65.values)


def spectrum_to_rgb(wavelengths, values, reflectance):
    """Linear sRGB of a sampled spectrum: a `reflectance` (under D65, clamped to [0, 1]) or an emission."""
    x, xyz, d65 = _tables()
    w = np.asarray(wavelengths, dtype=np.float64)
    inside = (x >= w[0]) & (x <= w[-1])
    y = np.interp(x, w, np.asarray(values, dtype=np.float64)) * inside
    weight = xyz * (d65[:, None] if reflectance else 1.0)
    rgb = XYZ_TO_SRGB @ ((weight * y[:, None]).sum(0) / weight[:, 1].sum())
    return np.clip(rgb, 0.0, 1.0) if reflectance else rgb
