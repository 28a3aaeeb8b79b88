"""docs/cli.md is generated from the code (``python -m imrbayes.cli.docs``): it must be current, and
name every command, option and ``--set`` key; ``fit --help`` keeps ``--set`` to one line per method."""

import dataclasses
from pathlib import Path

from click.testing import CliRunner

from imrbayes.cli import main
from imrbayes.cli.docs import cli_markdown, field_docs
from imrbayes.ensemble import METHODS

DOC = Path(__file__).resolve().parents[1] / "docs" / "cli.md"


def test_docs_cli_md_is_current():
    assert DOC.read_text(encoding="utf-8") == cli_markdown(), (
        "docs/cli.md is stale: regenerate it with `python -m imrbayes.cli.docs > docs/cli.md`"
    )


def test_docs_name_every_command_option_and_setting():
    text = cli_markdown()
    for name in main.list_commands(None):
        assert f"## `imrbayes {name}`" in text
        for prm in main.get_command(None, name).params:
            for opt in getattr(prm, "opts", []):
                if opt.startswith("--"):
                    assert f"`{opt}`" in text, (name, opt)
    for meth in METHODS.values():
        for f in dataclasses.fields(meth.settings_class):
            assert f"| `{f.name}` |" in text, (meth.name, f.name)


def test_field_docs_reads_defaults_and_attribute_docstrings():
    @dataclasses.dataclass
    class Toy:
        n_ens: int = 24
        """members per bubble"""
        #: window shift [samples]
        h: int = 5
        rtps: float = 0.7  # relaxation to prior spread

    assert field_docs(Toy) == [
        ("n_ens", "int", "24", "members per bubble"),
        ("h", "int", "5", "window shift [samples]"),
        ("rtps", "float", "0.7", "relaxation to prior spread"),
    ]


def test_fit_help_gives_set_one_line_per_method():
    out = CliRunner().invoke(main, ["fit", "--help"]).output
    block = out[out.index("--set KEY=VALUE") : out.index("--prior")]
    lines = [ln for ln in block.splitlines() if ln.strip()]
    assert "docs/cli.md" in block
    assert len(lines) <= len(METHODS) + 3, block
    for name in METHODS:
        assert sum(ln.strip().startswith(f"{name}:") for ln in lines) == 1, (name, block)
