"""The README's scanner-model table is the one the code prints, and every parameter has a source."""

import dataclasses
import re
from pathlib import Path

from tlssim.scanner import FARO_LS880_SOURCES, get_preset, parameter_table

README = Path(__file__).resolve().parents[1] / "README.md"


def test_every_parameter_has_a_source():
    fields = {f.name for f in dataclasses.fields(get_preset("faro-ls880"))} - {"name"}
    assert fields == set(FARO_LS880_SOURCES)
    assert all(len(text) > 10 for text in FARO_LS880_SOURCES.values())


def test_readme_table_matches_the_code():
    text = README.read_text()
    match = re.search(r"<!-- scanner-model-table:start -->\n(.*?)\n<!-- scanner-model-table:end -->", text, re.S)
    assert match, "README lacks the scanner-model table markers"
    assert match.group(1).strip() == parameter_table(get_preset("faro-ls880")).strip(), \
        "README scanner-model table is stale: paste the output of `tlssim presets faro-ls880`"
