import subprocess
import sys

from cnep.pipeline.cli.main import build_parser, main


def test_help_lists_subcommands_without_heavy_imports():
    code = (
        "import sys; from pipeline.cli.main import build_parser; build_parser(); "
        "heavy = [m for m in ('torch', 'rerun', 'cv2', 'mcap') if m in sys.modules]; "
        "print(','.join(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_unknown_subcommand_is_a_usage_error(capsys):
    try:
        main(["no-such-command"])
    except SystemExit as exc:
        assert exc.code == 2
    else:  # pragma: no cover - argparse always exits here
        raise AssertionError("argparse accepted an unknown subcommand")
    assert "invalid choice" in capsys.readouterr().err


def test_every_registered_command_has_help():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name, p in sub.choices.items():
        assert p.description, name
