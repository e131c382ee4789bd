import subprocess
import sys

from d2slam.cli import COMMANDS, build_parser, main
from d2slam.config import Config
from d2slam.errors import D2SlamError


def test_help_lists_every_command(capsys):
    parser = build_parser()
    text = parser.format_help()
    for name in COMMANDS:
        assert name in text


def test_no_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "usage" in capsys.readouterr().out


def test_console_entry_point_runs():
    out = subprocess.run([sys.executable, "-m", "d2slam.cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and "d2slam" in out.stdout


def test_error_names_file_and_line():
    err = D2SlamError("bad timestamp", path="rgb.txt", line=7)
    assert str(err) == "rgb.txt:7: bad timestamp"


def test_config_roundtrip_and_unknown_keys():
    cfg = Config.from_dict({"dynamics": {"rho": 0.5}})
    assert cfg.dynamics.rho == 0.5 and cfg.hash() != Config().hash()
    assert Config.from_dict(cfg.to_dict()) == cfg
    try:
        Config.from_dict({"dynamics": {"nope": 1}})
    except ValueError as exc:
        assert "nope" in str(exc)
    else:  # pragma: no cover
        raise AssertionError("unknown key accepted")


def test_every_help_renders(capsys):
    """`--help` of d2slam, of every command, of bench and of every bench topic prints and exits 0 (argparse %-formats
    help texts: an unescaped `%` in a topic's description crashed `d2slam bench --help`)."""
    import pytest

    from d2slam import bench

    argvs = [[], *([c] for c in COMMANDS), *(["bench", t] for t in bench.topics())]
    for argv in argvs:
        with pytest.raises(SystemExit) as exit_:
            main([*argv, "--help"])
        assert exit_.value.code == 0, argv
        out = capsys.readouterr().out
        assert "usage: d2slam" in out, argv
        assert "%%" not in out, argv  # descriptions are shown as written
    assert "3 % of the image" in build_parser()._subparsers._group_actions[0].choices["bench"].format_help()


def test_readme_lists_every_bench_topic():
    import re
    from pathlib import Path

    from d2slam import bench

    readme = (Path(__file__).resolve().parent.parent / "README.md").read_text()
    row = next(line for line in readme.splitlines() if line.startswith("| `d2slam bench TOPIC`"))
    listed = re.findall(r"`(\w+)`", row.split("|")[2])
    assert sorted(listed) == bench.topics()


def test_docs_outside_a_checkout_says_so_first(tmp_path, monkeypatch, capsys):
    import d2slam.paths as paths

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(paths, "REPO_ROOT", tmp_path)  # an installed package: no repository beside it
    assert main(["docs"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("d2slam: error: `d2slam docs` runs inside a d2slam checkout")
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "docs").exists()


def test_ctrl_c_while_the_commands_load_is_one_line(monkeypatch, capsys):
    import d2slam.cli as cli

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["study", "--help"]) == 130
    assert capsys.readouterr().err == "d2slam: interrupted\n"
