"""Realism of the synthetic people against real TUM fr3 frames (``d2slam.synth.realism``, ``d2slam bench realism``):
the statistics themselves, people's coverage and keypoint share over a walking sequence, textured shirts and plain
trousers, and the config driving the clothes."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from d2slam.config import SynthConfig
from d2slam.errors import D2SlamError
from d2slam.ranges import overridden
from d2slam.segmentation.base import PersonInstance
from d2slam.synth import realism
from d2slam.synth.textures import make_texture


@pytest.fixture(scope="module")
def ext():
    return realism.extractor()


# ---------------------------------------------------------------------------------------------- the statistics
def test_keypoints_on_masks_and_ratio():
    mask = np.zeros((480, 640), bool)
    mask[:, :320] = True
    kps = np.array([[10.2, 5.0], [319.4, 100.0], [319.6, 100.0], [639.0, 479.0]])  # 319.6 rounds to 320: outside
    assert realism.keypoints_on(kps, [mask, ~mask]) == [0.5, 0.5]
    assert realism.keypoints_on(np.zeros((0, 2)), [mask]) == [0.0]
    # frames with a sliver of mask have no ratio
    np.testing.assert_allclose(realism.ratio([0.1, 0.5, 0.01], [0.2, 0.5, 0.01]), [0.5, 1.0])
    assert np.isnan(realism.summary([])[0])
    with pytest.raises(D2SlamError, match="stride"):
        realism.sample_indices(300, 0)


def test_real_stats_with_a_given_segmenter_and_bad_image(tmp_path, ext):
    rng = np.random.default_rng(0)
    img = make_texture(rng, "poster", 640, 480)  # busy everywhere
    img[100:400, 200:400] = (128, 128, 128)  # a flat "person"
    cv2.imwrite(str(tmp_path / "a.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    mask = np.zeros((480, 640), bool)
    mask[100:400, 200:400] = True

    def segmenter(frame):
        assert frame.rgb.shape == (480, 640, 3)
        return [PersonInstance(mask, 0.9, (200, 100, 400, 400))]

    r = realism.real_stats([tmp_path / "a.png"], segmenter, ext=ext)
    assert r.area[0] == pytest.approx(mask.mean())
    assert r.n_kp[0] > 500
    assert r.kp[0] < 0.05 and r.ratio[0] < 0.3  # a flat region gets (almost) no keypoints
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    with pytest.raises(D2SlamError, match="bad.png"):
        realism.real_stats([tmp_path / "bad.png"], segmenter, ext=ext)
    with pytest.raises(D2SlamError, match="no real frames"):
        realism.real_stats([], segmenter, ext=ext)


# ---------------------------------------------------------------------------------------------- calibration
@pytest.mark.parametrize("scenario", ["walking_xyz", "walking_static"])
def test_walking_people_cover_and_feature_like_real_ones(scenario, ext):
    """Ten frames spread over a 300-frame walking sequence (seed 0, a development seed): people cover a tenth to a
    third of the image on average (real fr3 walking: 0.10-0.42, mean 0.24), at times much more, and carry
    fewer ORB keypoints than their area (real: ratio 0.1-1.0, mean 0.44) but clearly not none."""
    s = realism.synthetic_stats(scenario, 0, 300, 30, ext=ext)
    assert len(s.area) == 10 and (s.n_kp > 900).all()
    assert 0.1 <= s.area.mean() <= 0.34
    assert 0.2 <= s.area.max() <= 0.6
    # the room: textured share and FAST corners near the real frames' (0.48-0.62, 1480-3300)
    assert 0.38 <= s.textured.mean() <= 0.7 and 1300 <= s.corners.mean() <= 4000
    assert (s.dyn_area >= s.area).all()
    r = s.ratio
    assert len(r) >= 8
    assert 0.2 <= r.mean() <= 0.8
    assert s.kp.max() > 0.05  # people do yield features


def _corner_density(img, texels_per_m: float = 200.0) -> float:
    """FAST corners per square metre of a texture seen at 200 px per metre (about 2.7 m away)."""
    gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    s = 200.0 / texels_per_m
    gray = cv2.resize(gray, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    fast = cv2.FastFeatureDetector_create(threshold=20)
    return len(fast.detect(gray)) / gray.size * 200.0 ** 2


def test_people_textures_shirts_textured_trousers_plain():
    """Per square metre, trousers are plainer than the walls and every shirt has corners. (Measured: shirts have
    ~1000 FAST corners per m2 seen at 200 px/m against walls ~230, posters ~670: plainer shirts left people almost
    featureless for ORB in this busy room, which keeps the best-responding corners of the whole image; the per-frame
    calibration against real frames is the test above.)"""
    cfg, tpm = SynthConfig(), 420.0
    cloth = [_corner_density(make_texture(np.random.default_rng(s), "cloth", 210, 250, cfg, tpm), tpm)
             for s in range(12)]
    trousers = [_corner_density(make_texture(np.random.default_rng(s), "trousers", 105, 190, cfg, tpm), tpm)
                for s in range(6)]
    wall = np.mean([_corner_density(make_texture(np.random.default_rng(s), "wall", 300, 250), 220.0)
                    for s in range(4)])
    assert np.mean(trousers) < 0.5 * wall
    assert min(cloth) > 100
    for kind in ("skin", "hair"):
        t = make_texture(np.random.default_rng(1), kind, 100, 150, cfg, tpm)
        assert t.shape == (150, 100, 3) and t.dtype == np.uint8


def test_clothes_follow_the_config():
    plain = overridden(SynthConfig(), {"cloth": {"cloth_plain_prob": 1.0, "cloth_print_prob": 0.0,
                                                 "cloth_marks_per_m2": 0.0}})
    busy = overridden(SynthConfig(), {"cloth": {"cloth_plain_prob": 0.0, "cloth_marks_per_m2": 800.0,
                                                "cloth_contrast": 120}})
    d = {name: np.mean([_corner_density(make_texture(np.random.default_rng(s), "cloth", 210, 250, c, 420.0))
                        for s in range(6)]) for name, c in (("plain", plain), ("busy", busy))}
    assert d["plain"] < 0.2 * d["busy"]
    # same seed and config: same pixels
    a = make_texture(np.random.default_rng(3), "cloth", 120, 90, busy, 420.0)
    b = make_texture(np.random.default_rng(3), "cloth", 120, 90, busy, 420.0)
    assert np.array_equal(a, b)


def test_bench_realism_prints_the_table(capsys):
    from d2slam.cli import main

    assert main(["bench", "realism", "--no-real", "--scenario", "walking_rpy", "--frames", "20", "--stride", "10"]) == 0
    out = capsys.readouterr().out
    assert "walking_rpy s0 persons" in out and "walking_rpy s0 dynamic" in out and "targets" in out
    assert "TUM fr3" not in out
