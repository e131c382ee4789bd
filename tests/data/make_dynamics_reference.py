"""Writes ``tests/data/dynamics_reference.npz``: the outputs of every dynamics mode, with the default config, on
seeded toy scenes (two chained frames each) and a scene with persons at the image border.

``tests/test_dynamics_equivalence.py`` recomputes them and compares them (floats to a few ulps, so that another CPU's
rounding passes; decisions exactly): a change of any number of the dynamics modules shows up there. Re-run this script (``python tests/data/make_dynamics_reference.py``) only when a change of
the outputs is intended, and say so in the commit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d2slam.run.methods import DYNAMICS, get_filter

MODES = tuple(DYNAMICS)
from d2slam.dynamics.toy import two_view_scene
from d2slam.slam.hook import FilterInput

OUT = Path(__file__).with_name("dynamics_reference.npz")
# Diagnostics of ``filter.last`` compared (arrays), and its scalar counters.
FIELDS = ("z", "belief", "p_s", "inside", "uncertain", "in_area", "err", "p_g", "observed", "geo_dynamic", "fused",
          "prior", "belief_bayes", "zone", "oim", "mask_depth", "reproj_err", "depth_err", "pose_dynamic", "widening")
COUNTERS = ("f_found", "f_matches", "f_static_only")
# (seed, persons) of the toy scenes; small scenes keep the file small.
SCENES = ((0, 2), (2, 3), (3, 0), (7, 2))
N_KPS, N_MATCHES = 80, 60


def scenes():
    """(name, FilterInput for the first frame, whether a second chained frame follows) in a fixed order."""
    for seed, persons in SCENES:
        inp, _ = two_view_scene(seed, n_persons=persons, n_kps=N_KPS, n_matches=N_MATCHES)
        yield f"s{seed}p{persons}", inp, True
    inp, _ = two_view_scene(4, n_persons=2, n_kps=N_KPS, n_matches=N_MATCHES)
    masks = inp.masks.copy()
    masks[0, :, :40] = True  # cut by the left border
    masks[1, 400:, :] |= masks[1, 380:400, :].any(axis=0)  # reaches the bottom border
    inp.masks = masks
    yield "border", inp, False


def chained(inp: FilterInput, belief: np.ndarray) -> FilterInput:
    """The next frame: the same keypoints moved by 0.3 px, matched one to one, with the previous beliefs."""
    n = len(inp.kps)
    return FilterInput(**{**inp.__dict__, "prev_kps": inp.kps + 0.3, "prev_belief": belief,
                          "matches": np.column_stack([np.arange(n), np.arange(n)]).astype(np.int64)})


def outputs() -> dict[str, np.ndarray]:
    """``{mode/scene/frame/field: array}`` for every mode, scene, frame and field (absent fields are left out)."""
    out: dict[str, np.ndarray] = {}
    for mode in MODES:
        for name, inp, chain in scenes():
            f = get_filter(mode)
            frames = [inp]
            belief = f(inp)
            if chain:
                frames.append(chained(inp, belief))
            for k, frame_input in enumerate(frames):
                if k:
                    belief = f(frame_input)
                key = f"{mode}/{name}/{k}"
                out[f"{key}/beliefs"] = np.asarray(belief)
                for field in FIELDS:
                    value = getattr(f.last, field)
                    if value is not None:
                        out[f"{key}/{field}"] = np.asarray(value)
                out[f"{key}/counters"] = np.array([getattr(f.last, c) for c in COUNTERS], dtype=np.float64)
    return out


def save(values: dict[str, np.ndarray], path: Path = OUT) -> None:
    """Each distinct array once (many diagnostics are the same in several modes), with a key -> array index."""
    import json

    arrays: list[np.ndarray] = []
    seen: dict[tuple, int] = {}
    index = {}
    for key, a in values.items():
        ident = (a.dtype.str, a.shape, a.tobytes())
        if ident not in seen:
            seen[ident] = len(arrays)
            arrays.append(a)
        index[key] = seen[ident]
    np.savez_compressed(path, index=np.array(json.dumps(index, sort_keys=True)),
                        **{f"a{i}": a for i, a in enumerate(arrays)})


def load(path: Path = OUT) -> dict[str, np.ndarray]:
    """What :func:`save` wrote, as ``{key: array}``."""
    import json

    with np.load(path) as data:
        index = json.loads(str(data["index"]))
        return {key: data[f"a{i}"] for key, i in index.items()}


if __name__ == "__main__":
    save(outputs())
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")
