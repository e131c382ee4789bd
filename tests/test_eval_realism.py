"""The sensor's statistics, real against synthetic (``d2slam.eval.realism``, ``d2slam bench realism --real/--twin``):
each measure on a tiny case whose answer is known."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from d2slam.config import DEFAULT
from d2slam.errors import D2SlamError
from d2slam.eval import realism as R
from d2slam.run.observe import engine_log


def _texture(seed=0, h=480, w=640):
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur((rng.random((h, w)) * 255).astype(np.float32), (0, 0), 1.5)


def _box_blur(img, length, angle_deg):
    k = np.zeros((61, 61), np.float32)
    c = 30
    dx, dy = np.cos(np.radians(angle_deg)) * length / 2, np.sin(np.radians(angle_deg)) * length / 2
    cv2.line(k, (int(round((c - dx) * 16)), int(round((c - dy) * 16))),
             (int(round((c + dx) * 16)), int(round((c + dy) * 16))), 1.0, 1, cv2.LINE_AA, 4)
    return cv2.filter2D(img, -1, k / k.sum())


@pytest.mark.parametrize("length", [8, 12, 20, 30])
@pytest.mark.parametrize("angle", [0, 30, 90, 135])
def test_blur_extent_reads_a_box_blur_along_its_direction(length, angle):
    ev = DEFAULT.synth_eval
    img = _box_blur(_texture(), length, angle)
    d = (np.cos(np.radians(angle)), np.sin(np.radians(angle)))
    got = R.blur_extent(img, (320, 240), d, ev.realism_blur_patch, ev.realism_blur_max_lag, ev.realism_blur_min_dip)
    assert abs(got - length) <= 2  # the drawn line spans length + 1 px, the texture adds its own width
    # across the blur there is none to measure (the texture's own scale, a few px at most)
    across = R.blur_extent(img, (320, 240), (-d[1], d[0]), ev.realism_blur_patch, ev.realism_blur_max_lag,
                           ev.realism_blur_min_dip)
    assert not across >= length - 2
    # a patch reaching beyond the image is not measured
    assert np.isnan(R.blur_extent(img, (10, 240), d, ev.realism_blur_patch, ev.realism_blur_max_lag, 0.1))


def test_exposure_fit_recovers_the_slope():
    rng = np.random.default_rng(1)
    speed = rng.uniform(100, 1200, 300)
    extent = 3.0 + 0.018 * speed + rng.normal(0, 1.0, 300)
    extent[::10] = np.nan
    e, b, n = R.fit_exposure(speed, extent)
    assert abs(e - 0.018) < 0.001 and abs(b - 3.0) < 1.0 and n == 270
    with pytest.raises(D2SlamError, match="too few"):
        R.fit_exposure(speed[:5], extent[:5])


def test_noise_sigma_reads_white_noise_on_a_smooth_image():
    rng = np.random.default_rng(2)
    base = cv2.GaussianBlur(_texture(3), (0, 0), 8) * 0.3 + 60
    for sigma in (1.0, 3.0):
        img = base + rng.normal(0, sigma, base.shape)
        assert abs(R.noise_sigma(img) / sigma - 1) < 0.25


def test_track_lengths_count_runs_of_consecutive_frames():
    tracks = [np.array([1, 2, 3]), np.array([1, 3]), np.array([3, 4]), np.zeros(0, int), np.array([4])]
    # 1: frames 0-1 (2); 2: frame 0 (1); 3: frames 0-2 (3); 4: frame 2 (1), then frame 4 (1)
    assert sorted(R.track_lengths(tracks).tolist()) == [1, 1, 1, 2, 3]
    assert R.track_lengths([]).size == 0


def test_hole_kinds_and_border():
    z = np.full((100, 120), 2.0, np.float32)
    z[:, 60:] = 1.0  # a depth edge
    z[:, 55:60] = 0  # a hole on it (a shadow)
    z[20:24, 20:24] = 0  # a hole on a flat surface (a blob)
    z[:5] = 0  # the border
    k = R.hole_kinds(z, (5, 0, 0, 0), 0.05, 0.03)
    inner = 95 * 120
    assert np.isclose(k["edge"], 5 * 95 / inner) and np.isclose(k["blob"], 16 / inner)
    assert R.depth_border([z, z]) == (5, 0, 0, 0)
    zz = z.copy()
    zz[:, :3] = 0
    assert R.depth_border([z, z, zz]) == (5, 0, 0, 0)  # holes in a third of a column's pixels: not a border
    assert R.depth_border([z, zz]) == (5, 0, 3, 0)  # in half of them: a border


def test_edge_hole_runs_tell_the_shadowed_side():
    z = np.full((10, 60), 2.0, np.float32)
    z[:, 30:] = 1.0  # nearer on the right of column 30
    z[:, 22:30] = 0  # its shadow: 8 px on the farther side
    z[:, 45:48] = 0  # a hole on a flat surface: no edge, not counted
    z[:5, 10:12] = 3.0
    z[:5, 12:14] = 0  # 2 px between 3 m (left) and 2 m (right): nearer on the right too
    right, left = R.edge_hole_runs(z, (0, 0, 0, 0), 0.05, 0.03)
    assert sorted(right.tolist()) == [2] * 5 + [8] * 10 and left.size == 0
    right, left = R.edge_hole_runs(z[:, ::-1], (0, 0, 0, 0), 0.05, 0.03)
    assert right.size == 0 and sorted(left.tolist()) == [2] * 5 + [8] * 10


def test_percentiles_and_bins():
    assert np.allclose(R.pct([1, 2, 3, np.nan, np.inf], (0, 50, 100)), [1, 2, 3])
    assert np.isnan(R.pct([], (50,))).all()
    assert [b[2] for b in R.bins((1.0, 2.5))] == ["<1", "1-2.5", ">=2.5"]
    assert R.within(2.0, 2.4, 0.25) and not R.within(2.0, 2.6, 0.25) and not R.within(np.nan, 1.0, 0.25)


@pytest.fixture(scope="module")
def tiny_twin(tmp_path_factory):
    """Three frames of a twin (of the fixture recording)."""
    from d2slam.data.fixtures import recording_folder
    from d2slam.synth import generate
    from d2slam.synth.twin import read_recording

    root = tmp_path_factory.mktemp("tiny_twin")
    rec = read_recording(recording_folder(root))
    return generate("fr1_rpy_twin", root / "twin", frames=3, workers=1, progress=False, recording=rec)["out"]


def test_measure_and_compare_a_tiny_twin(tiny_twin):
    """The whole set of statistics on three frames of a twin, compared with itself."""
    from d2slam.data import open_sequence

    seq = open_sequence(tiny_twin)
    m = R.measure(seq, engine_log(seq, 3), stride=1)
    assert m.frames == 3 and len(m.sampled) == 3 and len(m.corners) == 3 and np.all(m.hole_share > 0.15)
    assert len(m.matches.epi) > 50 and np.nanmedian(m.matches.epi) < 5 and np.isfinite(m.speed[1:]).all()
    rows = R.comparison(m, m)
    assert rows[0] == ("frames tracked (engine, no filter)", f"{m.tracked}/3", f"{m.tracked}/3")
    assert all(a == b for _, a, b in rows)
    log = engine_log(seq, 3)
    tab, shift, readout = R.fit_time_offset(log, seq, np.array([-0.03, DEFAULT.synth.twin.rgb_time_shift, 0.03]),
                                            np.array([0.0]))
    assert tab.shape == (3, 1) and np.all(np.isfinite(tab))
    cons = R.depth_consistency(seq, [1, 2], DEFAULT.synth.twin.depth_time_shift,
                               readout=DEFAULT.synth.twin.depth_row_readout)
    assert cons.shape == (2,) and np.all(cons < 2.0)  # the twin's own timing: depth agrees to its noise


def test_bench_realism_real_against_twin(tiny_twin, capsys):
    from d2slam.cli import main

    assert main(["bench", "realism", "--real", str(tiny_twin), "--twin", str(tiny_twin), "--frames", "3"]) == 0
    out = capsys.readouterr().out
    assert "epipolar error (px) p50/p90/p99" in out and "FAST corners" in out
    assert "target: the synthetic sequence's epipolar p50 and p90 within 25 % of the real's" in out
    assert main(["bench", "realism", "--real", str(tiny_twin)]) == 2
    assert "--real and --twin go together" in capsys.readouterr().err
