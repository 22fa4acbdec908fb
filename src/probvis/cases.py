"""Occlusion cases of a (shading point, emitter) pair, as `VisibilityEstimator.classify` returns them."""
CASE_UNKNOWN = 0  # not classified: sampled, segments tested by the estimator as it sees fit
CASE_LIT = 1  # fully visible: integrated analytically, no shadow rays
CASE_SHADOWED = 2  # fully occluded: contributes nothing, no shadow rays
CASE_PENUMBRA = 3  # partly visible: sampled
N_CASES = 4
CASE_NAMES = ("unknown", "lit", "shadowed", "penumbra")
CASE_MASK = 3  # case & CASE_MASK is one of the four cases above
CASE_VERIFIED = 4  # flag on a lit or shadowed pair: sampled too, its segments return corrections (verification)
