"""Benchmark suites: named lists of cases, written in YAML.

A case is one simulated scan: a scene description (see
:func:`benchmarks.generators.build_scene`), scanner overrides, a seed and,
optionally, the names of the objects to score (default: every leaf). A suite
file looks like::

    name: quick
    description: a few single leaves, ...
    cases:
      - name: knife-edge
        scene: {builtin: knife-edge}
        targets: [plate]
      - name: "leaf-{distance_m}m-{incidence_deg}deg"
        scene: {generator: plate-leaf, length_m: 0.09}
        scanner: {n_subrays: 19}
        vary: {distance_m: [1.5, 3, 5], incidence_deg: [0, 60]}

A case may read its scene from a scene file of the :mod:`scenes` format,
``scene: {file: my-scene.yaml}``, the path relative to the suite file (the
file is checked when the suite is read, and its digest kept with the case).
``params`` sets method parameters for the case, by variant family or name
(``params: {prop-sfs: {n_smooth: 5}, step: {r_max_m: 0.6}}``). ``vary``
expands an entry into the Cartesian product of its lists; a key
``scanner.FIELD`` varies a scanner override and ``params.FAMILY.PARAM`` a
method parameter instead of a scene parameter, a dotted key such as
``surface_params.radius`` a nested scene parameter, and the name template
may use every varied key by its last part (``{FIELD}``).
The seed of a case defaults to a hash of its name, so the same case gets the
same scan in every suite. Files are read with ``yaml.safe_load``.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import yaml

from benchmarks.errors import BenchError
from benchmarks.generators import check_scene, resolve_scene_file
from tlssim.errors import ScanError
from tlssim.pattern import ScanWindow
from tlssim.scanner import ScannerModel, get_preset

#: Directory of the built-in suites (``<name>.yaml``).
SUITE_DIR = Path(__file__).parent / "suites"

_CASE_KEYS = {"name", "scene", "scanner", "seed", "targets", "params", "vary"}
#: Scanner-section keys a case may override besides the scanner-model fields.
_SECTION_KEYS = {"preset", "position", "orientation", "window"}


@dataclass(frozen=True)
class Case:
    """One simulated scan of a suite.

    Attributes
    ----------
    name : str
        Unique within its suite.
    scene : dict
        Scene description (``builtin`` or ``generator`` with parameters).
    scanner : dict
        Overrides of the scene's scanner section: window, position,
        orientation, preset, and scanner-model fields (e.g. ``step_deg``,
        ``divergence_deg``).
    seed : int
        Seed of the simulation.
    targets : tuple of str or None
        Objects to score (default: every leaf and analytic surface).
    params : dict
        Method parameters for this case, ``{family or variant name: {param:
        value}}`` (e.g. the thesis' smoothing and quantisation per synthetic
        experiment, or STEP's radius range for a large cylinder).
    """

    name: str
    scene: dict
    scanner: dict
    seed: int
    targets: tuple[str, ...] | None = None
    params: dict = dataclasses.field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready description (what workers receive and the store keeps)."""
        return {"name": self.name, "scene": self.scene, "scanner": self.scanner, "seed": self.seed,
                "targets": None if self.targets is None else list(self.targets), "params": self.params}

    @classmethod
    def from_dict(cls, data: dict) -> "Case":
        """Inverse of :meth:`to_dict`."""
        targets = data.get("targets")
        return cls(data["name"], dict(data["scene"]), dict(data.get("scanner") or {}), int(data["seed"]),
                   None if targets is None else tuple(targets), dict(data.get("params") or {}))


@dataclass(frozen=True)
class Suite:
    """A named list of cases.

    Attributes
    ----------
    name : str
        Suite name.
    description : str
        One paragraph.
    cases : tuple of Case
        The cases, in file order.
    source : str
        Where the suite came from (file path).
    """

    name: str
    description: str
    cases: tuple[Case, ...]
    source: str = ""

    def digest(self) -> str:
        """SHA-256 of the suite's name and cases: equal digests mean the same work."""
        text = json.dumps([self.name, [c.to_dict() for c in self.cases]], sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()


def case_seed(name: str) -> int:
    """Default seed of a case: the first 31 bits of the SHA-256 of its name."""
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "big") >> 1


def suite_names() -> list[str]:
    """Names of the built-in suites."""
    return sorted(p.stem for p in SUITE_DIR.glob("*.yaml"))


def load_suite(spec: str) -> Suite:
    """A built-in suite by name, or a suite file (YAML).

    Raises
    ------
    BenchError
        If the name is unknown and no such file exists, or the file is
        malformed (the message names the file, the case and the problem).
    """
    path = SUITE_DIR / f"{spec}.yaml" if spec in suite_names() else Path(spec)
    if not path.is_file():
        raise BenchError(f"unknown suite {spec!r}: not a built-in suite ({', '.join(suite_names())}) nor a file")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise BenchError(f"{path}: not a text file (a suite is UTF-8 YAML)") from None
    except yaml.YAMLError as exc:
        raise BenchError(f"{path}: not valid YAML ({exc})") from None
    try:
        return parse_suite(data, str(path))
    except BenchError as exc:
        raise BenchError(f"{path}: {exc}") from None


def parse_suite(data, source: str = "") -> Suite:
    """Build a :class:`Suite` from its parsed YAML document.

    Parameters
    ----------
    data : object
        The parsed YAML document (a mapping with ``name``, ``cases``, optional
        ``description``).
    source : str
        Where the document came from (file path or name), for messages.

    Returns
    -------
    Suite
        The suite, its cases validated.

    Raises
    ------
    BenchError
        On missing or unknown keys, bad values, empty or duplicated cases.
    """
    if not isinstance(data, dict) or not isinstance(data.get("name"), str) or not data["name"]:
        raise BenchError("a suite must be a mapping with a non-empty 'name' and a list of 'cases'")
    unknown = sorted(set(data) - {"name", "description", "cases"})
    if unknown:
        raise BenchError(f"unknown suite key(s) {unknown}; allowed: name, description, cases")
    entries = data.get("cases")
    if not isinstance(entries, list) or not entries:
        raise BenchError("'cases' must be a non-empty list")
    cases: list[Case] = []
    for index, entry in enumerate(entries):
        label = f"case #{index + 1}" + (f" ({entry.get('name')})" if isinstance(entry, dict) else "")
        try:
            cases.extend(_expand(entry, Path(source).parent if source else Path.cwd()))
        except BenchError as exc:
            raise BenchError(f"{label}: {exc}") from None
    names = [c.name for c in cases]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise BenchError(f"case names must be unique; repeated: {repeated}")
    return Suite(data["name"], str(data.get("description", "")), tuple(cases), source)


def check_scanner(overrides: dict) -> None:
    """Refuse unknown scanner overrides and invalid values before anything runs.

    Parameters
    ----------
    overrides : dict
        A case's ``scanner`` entry: section keys (window, position,
        orientation, preset) and scanner-model fields.

    Raises
    ------
    BenchError
        Naming the unknown key or the invalid value and what is allowed.
    """
    allowed = ({f.name for f in dataclasses.fields(ScannerModel)} - {"name"}) | _SECTION_KEYS
    unknown = sorted(set(overrides) - allowed)
    if unknown:
        raise BenchError(f"unknown scanner override(s) {unknown}; allowed: {sorted(allowed)}")
    fields = {k: v for k, v in overrides.items() if k not in _SECTION_KEYS}
    try:
        model = get_preset(overrides.get("preset", "faro-ls880"), **fields)
        if "window" in overrides:
            window = overrides["window"]
            if not isinstance(window, dict) or not {"theta_deg", "psi_deg"} <= set(window):
                raise ScanError(f"window must give theta_deg and psi_deg ranges in degrees, got {window!r}")
            ScanWindow(window["theta_deg"], window["psi_deg"], window.get("step_deg", model.step_deg))
    except (ScanError, TypeError) as exc:
        raise BenchError(f"scanner: {exc}") from None


def _expand(entry, base_dir: Path) -> list[Case]:
    if not isinstance(entry, dict):
        raise BenchError(f"a case must be a mapping, got {entry!r}")
    unknown = sorted(set(entry) - _CASE_KEYS)
    if unknown:
        raise BenchError(f"unknown key(s) {unknown}; allowed: {sorted(_CASE_KEYS)}")
    if not isinstance(entry.get("name"), str) or not entry["name"]:
        raise BenchError("every case needs a non-empty 'name'")
    scene, scanner = entry.get("scene"), entry.get("scanner") or {}
    if not isinstance(scene, dict):
        raise BenchError("'scene' must be a mapping with 'builtin', 'generator', 'file' or 'heightfield'")
    if not isinstance(scanner, dict):
        raise BenchError(f"'scanner' must be a mapping of scanner-model overrides, got {scanner!r}")
    targets = entry.get("targets")
    if targets is not None and not (isinstance(targets, list) and all(isinstance(t, str) for t in targets)):
        raise BenchError(f"'targets' must be a list of object names, got {targets!r}")
    params = entry.get("params") or {}
    if not (isinstance(params, dict) and all(isinstance(v, dict) for v in params.values())):
        raise BenchError(f"'params' must map variant families or names to parameter mappings, got {params!r}")
    seed = entry.get("seed")
    if seed is not None and not isinstance(seed, int):
        raise BenchError(f"'seed' must be an integer, got {seed!r}")
    vary = entry.get("vary") or {}
    if not isinstance(vary, dict) or not all(isinstance(v, list) and v for v in vary.values()):
        raise BenchError("'vary' must map parameter names to non-empty lists of values")
    cases = []
    for values in itertools.product(*vary.values()):
        case = {"scene": copy.deepcopy(scene), "scanner": dict(scanner), "params": copy.deepcopy(params)}
        fields = {}
        for key, value in zip(vary, values):
            path = key.split(".")
            target = case if path[0] in ("scanner", "params") else case["scene"]
            for part in path[:-1]:
                if not isinstance(target.setdefault(part, {}), dict):
                    raise BenchError(f"vary key {key!r}: {part!r} is not a mapping")
                target = target[part]
            target[path[-1]] = value
            fields[path[-1]] = value
        case_scene, case_scanner, case_params = case["scene"], case["scanner"], case["params"]
        try:
            name = entry["name"].format(**fields)
        except (KeyError, IndexError, ValueError) as exc:
            raise BenchError(f"name template {entry['name']!r} uses a field that is not varied ({exc})") from None
        if isinstance(case_scene, dict) and "file" in case_scene and "sha256" not in case_scene:
            case_scene = resolve_scene_file(case_scene, base_dir)
        check_scene(case_scene)
        check_scanner(case_scanner)
        cases.append(Case(name, case_scene, case_scanner, case_seed(name) if seed is None else seed,
                          None if targets is None else tuple(targets), case_params))
    if vary and len({c.name for c in cases}) < len(cases):
        raise BenchError(f"name template {entry['name']!r} must use every varied key to give unique names")
    return cases
