"""Hand-built parts for the container join's tests: each part a patch of its own."""

import numpy as np


def stacked_parts(parts, segs):
    """Stack ``parts`` ((points, normals) pairs) with their segment ids ``segs``.

    Return points, normals, the segment of every point, its part (as patch label) and the
    row bounds of the parts.
    """
    sizes = [len(p) for p, _ in parts]
    points = np.vstack([p for p, _ in parts])
    normals = np.vstack([q for _, q in parts])
    comp = np.repeat(segs, sizes)
    labels = np.repeat(np.arange(len(parts)), sizes)
    return points, normals, comp, labels, np.cumsum([0] + sizes)


def concave_oracle(concave_flags, asked=None):
    """Return the concavity test of the parts: ``concave_flags`` tell which are concave.

    The patch ids it is asked about go to ``asked`` when given.
    """
    flags = np.asarray(concave_flags, dtype=bool)

    def concave(which):
        if asked is not None:
            asked.extend(which.tolist())
        out = np.zeros(len(flags), dtype=bool)
        out[which] = flags[which]
        return out

    return concave


def labels_of_parts(out, bounds):
    """Return the set of output labels of every part's rows."""
    return [set(out[s:e].tolist()) for s, e in zip(bounds[:-1], bounds[1:])]
