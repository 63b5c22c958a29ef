"""The command line itself: every subcommand's --help renders, and the top-level help lists them."""

from __future__ import annotations

import subprocess
import sys

import pytest

from nerfkit.cli import COMMANDS, main


@pytest.mark.parametrize("command", COMMANDS)
def test_every_subcommand_help_renders(command, capsys):
    # argparse %-formats help strings: a stray '%' in one option's help used to crash --help.
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: nerfkit {command}")
    assert "--" in out  # at least one option is described


def test_top_level_help_lists_every_command(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for command in COMMANDS:
        assert command in out, command


def test_top_level_help_does_not_import_torch():
    # Registering `train` imports torch for its model flags; `nerfkit --help` must not pay that.
    code = ("import sys\nfrom nerfkit.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "False"


def test_options_before_the_command_still_find_it(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--verbose", "eval", "--help"])
    assert e.value.code == 0
    assert capsys.readouterr().out.startswith("usage: nerfkit eval")
