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


def test_ctrl_c_while_the_commands_load_is_one_line(monkeypatch, capsys):
    import d2slam.cli as cli

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["study", "--help"]) == 130
    assert capsys.readouterr().err == "d2slam: interrupted\n"
