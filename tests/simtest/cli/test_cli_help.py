"""Every command's --help renders (argparse formats help strings lazily, so a stray '%' only fails here)."""

from __future__ import annotations

import pytest

from simtest.cli import COMMAND_MODULES, main


@pytest.mark.parametrize("argv", [["--help"]] + [[c, "--help"] for c in COMMAND_MODULES] +
                         [["bench", "generate", "--help"], ["bench", "grasp", "--help"], ["bench", "metrics", "--help"],
                          ["bench", "corruptions", "--help"], ["bench", "panda", "--help"], ["train", "keypoints", "--help"],
                          ["objects", "list", "--help"]])
def test_help_renders(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    assert "usage: simtest" in capsys.readouterr().out
