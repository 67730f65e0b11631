"""What the scene benchmarks read from a mock's truth table and from a run's result."""

import numpy as np

from lensdual._doubts import doubts_of


def patch_sources(truth):
    """The sources (the truth's ``source``) whose image lies on the diffuse patch of
    ``render_mock_images(patch=...)``; none without a patch."""
    if "patch1" not in truth.colnames:
        return np.array([], dtype=int)
    under = np.asarray(truth["patch1"], bool) | np.asarray(truth["patch2"], bool)
    return np.asarray(truth["source"])[under]


def flux_doubtful(result):
    """Per pair, whether its flux ratio is doubtful (a reason in ``flux_doubt``)."""
    return doubts_of(result, "flux_doubt") != ""
