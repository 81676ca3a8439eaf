"""Fixtures for the data-layer tests."""
from __future__ import annotations

import pytest

from planar_vo import cli


@pytest.fixture
def run_cli(monkeypatch, capsys):
    """``run_cli(*argv) -> (exit code, stdout, stderr)`` through ``planar_vo.cli.main``.

    Only this package's commands are registered, so other commands' imports do not matter.
    """
    monkeypatch.setattr(cli, "COMMANDS", {k: v for k, v in cli.COMMANDS.items()
                                          if k in ("info", "convert")})

    def run(*argv):
        code = cli.main([str(a) for a in argv])
        out = capsys.readouterr()
        return code, out.out, out.err
    return run
