"""The dynamics modules reproduce their reference outputs: every mode, every diagnostic, over two chained frames of
seeded toy scenes and a scene with persons at the image border (``tests/data/dynamics_reference.npz``, written by
``tests/data/make_dynamics_reference.py`` from the default config).

The reference was written on one CPU; another CPU's SIMD paths (numpy, OpenBLAS) may round the last bits
differently, so floats are compared with a tolerance far below any modelled quantity and above float32 rounding
(``RTOL``, ``ATOL``), decisions (booleans, integers) exactly. Byte-identity is a property of one machine: the same
inputs computed twice give the same bytes (``test_outputs_are_byte_identical_within_one_machine``)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent / "data"))
import make_dynamics_reference as R  # noqa: E402

from d2slam.run.methods import DYNAMICS, get_filter  # noqa: E402

MODES = tuple(DYNAMICS)


# Another CPU's rounding changes a value by a few ulps: keypoint depth is float32, so by one float32 ulp there
# (1.2e-7 relative, with the SIMD paths of x86-64-v2 forced) and the beliefs computed from it by up to 4e-8 relative;
# with AVX2 instead of AVX-512, 3e-16. A real change of the modules changes them by orders of magnitude more.
RTOL, ATOL = 1e-6, 1e-9
# The pose test's residuals are differences of nearly equal float32 depths (or positions) over their noise: one
# float32 ulp of a 2 m depth moves a depth residual by about 2.4e-7 sigma on x86-64-v2 (measured), which is a large
# relative change of a residual near 0. They are compared with this absolute tolerance, far below any threshold.
RESIDUALS, RESIDUAL_ATOL = ("depth_err", "reproj_err"), 1e-5


@pytest.fixture(scope="module")
def reference():
    return R.load()


@pytest.fixture(scope="module")
def current():
    return R.outputs()


def test_reference_covers_every_mode_and_scene(reference):
    keys = {k.rsplit("/", 1)[0] for k in reference}
    assert {k.split("/")[0] for k in keys} == set(MODES)
    assert len(keys) == len(MODES) * (2 * len(R.SCENES) + 1)


@pytest.mark.parametrize("mode", MODES)
def test_outputs_equal_the_reference(mode, reference, current):
    ref = {k: v for k, v in reference.items() if k.startswith(mode + "/")}
    now = {k: v for k, v in current.items() if k.startswith(mode + "/")}
    assert sorted(now) == sorted(ref)  # the same diagnostics are present
    for key, value in ref.items():
        assert now[key].dtype == value.dtype, key
        if np.issubdtype(value.dtype, np.floating):
            atol = RESIDUAL_ATOL if key.rsplit("/", 1)[-1] in RESIDUALS else ATOL
            np.testing.assert_allclose(now[key], value, rtol=RTOL, atol=atol, equal_nan=True, err_msg=key)
        else:
            np.testing.assert_array_equal(now[key], value, err_msg=key)


def test_outputs_are_byte_identical_within_one_machine(current):
    again = R.outputs()
    assert sorted(again) == sorted(current)
    for key, value in current.items():
        assert again[key].tobytes() == value.tobytes(), key


def test_the_tolerance_catches_a_real_change(reference):
    """A change of one part in 100,000 of a float diagnostic fails the comparison."""
    key = next(k for k, v in reference.items() if np.issubdtype(v.dtype, np.floating) and np.abs(v).max() > 0)
    value = reference[key]
    changed = value * (1 + 1e-5)
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(changed, value, rtol=RTOL, atol=ATOL, equal_nan=True)


def test_the_oim_path_is_exercised(reference):
    """The references hold OIM flips, not only skipped OIMs (and the filter flips there now too)."""
    assert reference["d2slam/s7p2/0/oim"].any()
    inp = next(s for name, s, _ in R.scenes() if name == "s7p2")
    f = get_filter("d2slam")
    f(inp)
    assert f.last.oim.any()
