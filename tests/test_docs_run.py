"""Every command and Python block of README.md and docs/*.md runs as written (issue 15 item 8).

Commands are parsed by their program's own argument parser as written, then run in document order in one
folder, in this process (console scripts are ``main(argv)`` functions). The few long ones run a small
equivalent listed, with the reason, in ``tests/docs_commands.yaml`` (read its header).
"""

import re
import shlex
import subprocess
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
MAPPING = yaml.safe_load((Path(__file__).with_name("docs_commands.yaml")).read_text())
PROGRAMS = ("tlssim", "tlsbench", "leafsfs", "woody", "make")
#: Placeholders of the docs and what the parse check puts in their place.
PLACEHOLDERS = {"SCAN.npz|.e57|.ptx": "scan.npz", "OUTDIR": "out", "RUN_A": "a", "RUN_B": "b", "Z": "0"}
TINY_SUITE = {"name": "tiny", "cases": [
    {"name": "leaf-3m", "scene": {"generator": "plate-leaf", "distance_m": 3.0}},
    {"name": "edge", "scene": {"builtin": "knife-edge"}, "targets": ["plate"]},
]}


def blocks() -> list[tuple[str, str, str]]:
    """Every fenced block of the docs: (file name, language, text)."""
    found = []
    for path in DOCS:
        for match in re.finditer(r"^```(\w*)\n(.*?)^```", path.read_text(), re.S | re.M):
            found.append((path.name, match.group(1), match.group(2)))
    return found


def commands(text: str) -> list[str]:
    """The commands of a shell block: comments and ``.venv/bin/`` dropped, comment-only lines skipped, lines
    continued by a backslash joined."""
    lines, pending = [], ""
    for line in text.splitlines():
        part = line.split(" #", 1)[0].strip()
        if part.startswith("#"):
            continue
        if part.endswith("\\"):
            pending += part[:-1].strip() + " "
            continue
        command = (pending + part).strip().removeprefix(".venv/bin/")
        pending = ""
        if command:
            lines.append(command)
    return lines


def steps() -> list[tuple[str, str]]:
    """The docs in order: ("command", line) and ("python", block); yaml blocks are the user's files."""
    order = []
    for _, language, text in blocks():
        if language == "python":
            order.append(("python", text))
        elif language in ("", "bash", "sh"):
            order += [("command", c) for c in commands(text)]
    return order


def parser_of(program: str):
    import benchmarks.cli
    import leafsfs.cli
    import tlssim.cli
    import woody.cli

    return {"tlssim": tlssim.cli, "tlsbench": benchmarks.cli, "leafsfs": leafsfs.cli, "woody": woody.cli}[program]


def as_written(command: str) -> list[str]:
    """The command's arguments with placeholders filled in and optional ``[...]`` parts included."""
    for placeholder, value in PLACEHOLDERS.items():
        command = re.sub(rf"(?<![\w.-]){re.escape(placeholder)}(?![\w-])", value, command)
    return shlex.split(command.replace("[", " ").replace("]", " "))


def test_every_command_is_a_known_program_and_every_mapping_is_used():
    listed = [c for kind, c in steps() if kind == "command"]
    assert len(listed) > 30, "the docs' commands were not found"
    unknown = [c for c in listed if c.split()[0] not in PROGRAMS]
    assert not unknown, f"commands of programs this test does not know: {unknown}"
    first_lines = [text.splitlines()[0] for kind, text in steps() if kind == "python"]
    stale = set(MAPPING) - set(listed) - set(first_lines)
    assert not stale, f"docs_commands.yaml lists commands the docs no longer have: {stale}"
    for command, entry in MAPPING.items():
        assert entry.get("why"), f"docs_commands.yaml: `{command}` has no reason"
        if command in listed:  # the small equivalent runs the same program and sub-command
            program, word = command.split()[:2]
            assert any(run.split()[0] == program and word in run.split() for run in entry.get("run", [command])), command


def make_commands(target: str) -> list[str]:
    """The project's commands a make target runs (``make -n``, ``.venv/bin/`` dropped)."""
    printed = subprocess.run(["make", "-n", "-C", str(ROOT), target], capture_output=True, text=True, timeout=60)
    return [line.strip().removeprefix(".venv/bin/").removeprefix("$(VENV)/bin/") for line in printed.stdout.splitlines()
            if line.strip().startswith(tuple(f".venv/bin/{p}" for p in PROGRAMS))]


def test_make_bench_runs_the_main_job():
    assert "tlsbench main -o bench-out" in make_commands("bench")
    assert commands("a \\\n  b   # comment\n# only a comment\n.venv/bin/c d") == ["a b", "c d"]


@pytest.mark.parametrize("command", sorted({c for kind, c in steps() if kind == "command" and not c.startswith("make ")}
                                           | set(make_commands("bench"))))
def test_every_command_parses_as_written(command):
    argv = as_written(command)
    try:
        parser_of(argv[0]).build_parser().parse_args(argv[1:])
    except SystemExit as exit_:
        pytest.fail(f"`{command}` does not parse (exit {exit_.code}): a wrong option or sub-command")


def _user_files(folder: Path) -> None:
    """The files the docs expect from the user (see docs_commands.yaml)."""
    import laspy

    from woody.synthetic import sample_cylinders

    scene_example = next(text for name, language, text in blocks() if name == "scene-format.md" and language == "yaml")
    (folder / "my-scene.yaml").write_text(scene_example)
    (folder / "part.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                     "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                                     "end_header\n0 0 0\n0.2 0 0\n0 0 0.2\n3 0 1 2\n")
    stem = [{"start": [0, 0, 0], "end": [0, 0, 2.0], "radius_m": 0.12, "radius_end_m": 0.1},
            {"start": [0, 0, 1.6], "end": [0.6, 0, 2.2], "radius_m": 0.04, "radius_end_m": 0.03}]
    cloud = sample_cylinders(stem, 5e3, seed=1).points
    ground = np.c_[np.random.default_rng(2).uniform(-1, 1, (2000, 2)), np.zeros(2000)]
    points = np.vstack([cloud, ground])
    las = laspy.create(point_format=0, file_version="1.2")
    las.header.scales = [0.001] * 3
    las.x, las.y, las.z = points.T
    las.write(str(folder / "tree.laz"))
    (folder / "tree.ply").write_text(f"ply\nformat ascii 1.0\nelement vertex {len(points)}\nproperty double x\n"
                                     "property double y\nproperty double z\nend_header\n"
                                     + "\n".join(f"{x:.4f} {y:.4f} {z:.4f}" for x, y, z in points) + "\n")
    (folder / "tiny.yaml").write_text(yaml.safe_dump(TINY_SUITE))


def _run(command: str, folder: Path) -> int:
    argv = shlex.split(command)
    if argv[0] == "make":
        return subprocess.run(argv + ["-C", str(ROOT)], capture_output=True, timeout=60).returncode
    shown = warnings.showwarning  # run_main redirects warnings to one line: keep pytest's own
    try:
        return parser_of(argv[0]).main(argv[1:])
    except SystemExit as exit_:
        return exit_.code
    finally:
        warnings.showwarning = shown


def test_every_command_and_python_block_runs(tmp_path, monkeypatch, llvm, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("TLSBENCH_CACHE_DIR", str(tmp_path / "cache"))
    _user_files(tmp_path)
    spent = []
    for kind, text in steps():
        entry = MAPPING.get(text if kind == "command" else text.splitlines()[0], {})
        for before in entry.get("before", []):
            assert _run(before, tmp_path) == 0, f"`{before}` (made for `{text}`) failed: {capsys.readouterr().err}"
        start = time.perf_counter()
        if kind == "python":
            try:
                exec(compile(text, "<docs python block>", "exec"), {})
            except Exception as error:  # noqa: BLE001 - any failure of a block is the test's failure
                pytest.fail(f"the python block failed: {type(error).__name__}: {error}\n{text}")
        for command in entry.get("run", [text]) if kind == "command" else []:
            status = _run(command, tmp_path)
            assert status == entry.get("exit", 0), (f"`{command}` (for the docs' `{text}`) exited {status}: "
                                                    f"{capsys.readouterr().err[-2000:]}")
        spent.append((time.perf_counter() - start, text.splitlines()[0]))
    with capsys.disabled():  # where the time goes (pytest -s shows it)
        print("\nslowest docs steps:", ", ".join(f"{line} {seconds:.1f} s" for seconds, line in sorted(spent)[-6:]))
    for name in ("knife.npz", "leaf.e57", "corrected.npz", "calibration.json", "out/report.html", "sweeps",
                 "recon/traits.json", "woody-exp", "history.png"):
        assert (tmp_path / name).exists(), f"the docs promise {name}"
