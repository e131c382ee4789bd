"""`d2slam bench dynamics` on toy scenes and on the hook inputs of a (small, generated) synthetic sequence."""

import pytest

from d2slam.cli import main


@pytest.fixture(scope="module")
def walking(tmp_path_factory):
    from d2slam.synth import generate

    root = tmp_path_factory.mktemp("bench") / "walking_xyz"
    generate("walking_xyz", str(root), frames=6, seed=1, workers=1, progress=False)
    return root


def test_recorded_inputs_are_the_engines_hook_inputs(walking):
    from d2slam.bench.dynamics import recorded_inputs

    inps = recorded_inputs(str(walking), 6)
    assert [inp.frame_index for inp in inps] == [1, 2, 3, 4, 5]
    assert all(inp.masks is not None and len(inp.kps) > 100 and len(inp.matches) > 30 for inp in inps)
    assert all(len(inp.prev_kp_depth) == len(inp.prev_kps) for inp in inps)
    # the previous frame's grey image, for the flow of d2slam-flow
    assert all(inp.prev_gray is not None and inp.prev_gray.shape == inp.gray.shape for inp in inps)
    assert all(a.gray is b.prev_gray for a, b in zip(inps, inps[1:]))
    assert all(a.depth is b.prev_depth for a, b in zip(inps, inps[1:]))


def test_bench_dynamics_on_a_sequence_and_on_toy_scenes(walking, capsys):
    assert main(["bench", "dynamics", "--sequence", str(walking), "--sequence-frames", "4", "--frames", "3",
                 "--warmup", "1"]) == 0
    out = capsys.readouterr().out
    assert "hook inputs of frames 1-3" in out and "geometric" in out and "process CPU time median" in out
    assert main(["bench", "dynamics", "--scenes", "2", "--frames", "3", "--warmup", "1"]) == 0
    assert "1000 keypoints, 800 matches, 2 masks" in capsys.readouterr().out
    # one frame gives no hook input: a clear error, not a traceback
    assert main(["bench", "dynamics", "--sequence", str(walking), "--sequence-frames", "1"]) != 0
    assert "--sequence needs at least 2 frames" in capsys.readouterr().err


def test_bench_dynamics_flow_mode(walking, capsys):
    assert main(["bench", "dynamics", "--sequence", str(walking), "--sequence-frames", "4", "--frames", "3",
                 "--warmup", "1", "--method", "d2slam-flow"]) == 0
    out = capsys.readouterr().out
    assert "of which the LK flow median" in out and "the paper's modules without it" in out
    # toy scenes have no images: a clear refusal for the flow mode, a note with --method all
    assert main(["bench", "dynamics", "--scenes", "2", "--frames", "2", "--warmup", "0", "--method", "d2slam-flow"]) == 2
    assert "timed with --sequence only" in capsys.readouterr().out
    assert main(["bench", "dynamics", "--scenes", "2", "--frames", "2", "--warmup", "0", "--method", "all"]) == 0
    out = capsys.readouterr().out
    assert "method d2slam-flow: needs grey images" in out and "method no-oim" in out
    assert main(["bench", "dynamics", "--method", "dynaslam"]) != 0
    assert "unknown method" in capsys.readouterr().err
