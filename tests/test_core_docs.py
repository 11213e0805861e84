"""The README's scanner-model table is the one the code prints (sources are checked in test_physics_detector)."""

import re
from pathlib import Path

from tlssim.scanner import get_preset, parameter_table

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_table_matches_the_code():
    text = README.read_text()
    match = re.search(r"<!-- scanner-model-table:start -->\n(.*?)\n<!-- scanner-model-table:end -->", text, re.S)
    assert match, "README lacks the scanner-model table markers"
    assert match.group(1).strip() == parameter_table(get_preset("faro-ls880")).strip(), \
        "README scanner-model table is stale: paste the output of `tlssim presets faro-ls880`"


def test_relative_links_of_the_docs_resolve():
    """Every relative link of README.md and docs/**.md names a file or folder of the repository (the README links
    to the lab notebook, docs/notebook/, where the history moved)."""
    root = README.parent
    broken = []
    for path in [README, *sorted((root / "docs").rglob("*.md"))]:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", path.read_text()):
            if "://" not in target and not (path.parent / target).exists():
                broken.append(f"{path.relative_to(root)}: {target}")
    assert not broken, f"links to missing files: {broken}"
