"""The occlusion map's case shares as images: one RGB image per emitter (`--case-image`)."""
from pathlib import Path

import numpy as np

from ..errors import ProbvisError
from .image import write_image


def case_colours(shares):
    """(h, w, 4) shares of the occlusion cases (unknown, lit, shadowed, penumbra) as RGB: red penumbra,
    green lit, blue shadowed, grey unknown."""
    shares = np.asarray(shares)
    if shares.ndim < 1 or shares.shape[-1] != 4 or shares.dtype.kind not in "fiu":
        raise ProbvisError(f"case shares are an (..., 4) array of numbers (unknown, lit, shadowed, penumbra), got "
                           f"{shares.dtype} of shape {shares.shape}")
    unknown, lit, shadowed, penumbra = (shares[..., c] for c in range(4))
    return np.stack([penumbra + 0.5 * unknown, lit + 0.5 * unknown, shadowed + 0.5 * unknown], axis=-1)


def case_image_paths(path, n_emitters):
    """The files `write_case_images` writes for `n_emitters`: `path` itself for one, `name-e<k>.ext` for several."""
    p = Path(path)
    return [str(p) if n_emitters == 1 else str(p.with_name(f"{p.stem}-e{e}{p.suffix}")) for e in range(n_emitters)]


def write_case_images(path, cases):
    """Write the (h, w, emitters, 4) case-share AOV as one image per emitter (`name-e<k>.ext` when there are
    several); returns the paths written."""
    cases = np.asarray(cases)
    if cases.ndim != 4 or cases.shape[3] != 4 or cases.dtype.kind not in "fiu":
        raise ProbvisError(f"cannot write '{path}': case shares are an (h, w, emitters, 4) array, got "
                           f"{cases.dtype} of shape {cases.shape}")
    paths = case_image_paths(path, cases.shape[2])
    for e, out in enumerate(paths):
        write_image(out, case_colours(cases[:, :, e, :]))
    return paths
