"""The results store: one SQLite file holding every benchmark run.

Tables:

- ``runs``: run id, creation time (UTC), git commit, machine, suite name and
  digest, configuration (variants and parameters) and its digest, status
  (``running`` / ``complete``), notes (e.g. the sweeps of a main job).
- ``results``: one row per (run, case, variant): the variant's family and
  parameters, the case description, the metrics (JSON, with the per-leaf
  scores), runtime, peak memory, simulation time, error message and finish
  time. ``(run_id, case_name, variant)`` is the primary key, so a result is
  never stored twice.

Several processes may write to the same file: the database runs in WAL
mode, every write is one ``BEGIN IMMEDIATE`` transaction, and writes retry
with back-off while another writer holds the lock. A run that is stopped
keeps every finished case; :meth:`Store.done_pairs` tells a resumed run what
is left.
"""

from __future__ import annotations

import json
import os
import platform
import secrets
import sqlite3
import subprocess
import time
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

from benchmarks.errors import BenchError

_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    run_id TEXT PRIMARY KEY,
    created TEXT NOT NULL,
    git_commit TEXT NOT NULL,
    machine TEXT NOT NULL,
    suite TEXT NOT NULL,
    suite_digest TEXT NOT NULL,
    config TEXT NOT NULL,
    config_digest TEXT NOT NULL,
    status TEXT NOT NULL,
    finished TEXT,
    notes TEXT NOT NULL DEFAULT '{}'
);
CREATE TABLE IF NOT EXISTS results (
    run_id TEXT NOT NULL REFERENCES runs(run_id),
    case_name TEXT NOT NULL,
    variant TEXT NOT NULL,
    family TEXT NOT NULL,
    params TEXT NOT NULL,
    case_spec TEXT NOT NULL,
    metrics TEXT NOT NULL,
    runtime_s REAL,
    peak_mem_mb REAL,
    simulate_s REAL,
    error TEXT,
    finished TEXT NOT NULL,
    PRIMARY KEY (run_id, case_name, variant)
);
"""

_RESULT_COLUMNS = ("case_name", "variant", "family", "params", "case_spec", "metrics", "runtime_s",
                   "peak_mem_mb", "simulate_s", "error", "finished")
_JSON_COLUMNS = {"params", "case_spec", "metrics", "machine", "config", "notes"}
#: How long a writer waits for the lock in total, s.
LOCK_WAIT_S = 120.0


def utc_now() -> str:
    """Current UTC time, ISO 8601 with microseconds."""
    return datetime.now(timezone.utc).isoformat(timespec="microseconds")


def git_commit(path: Path | None = None) -> str:
    """Commit of the code (``<sha>`` or ``<sha>-dirty``; ``unknown`` outside git)."""
    where = str(path or Path(__file__).resolve().parent)
    try:
        sha = subprocess.run(["git", "-C", where, "rev-parse", "HEAD"], capture_output=True, text=True,
                             check=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", where, "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return f"{sha}-dirty" if dirty else sha


def machine_info() -> dict:
    """Host name, platform, processor count and Python version."""
    return {"host": platform.node(), "platform": platform.platform(), "cpus": os.cpu_count(),
            "python": platform.python_version()}


class Store:
    """A results database (created on first use).

    Parameters
    ----------
    path : str or Path
        SQLite file.
    create : bool
        Create the file (and its tables) if needed. Commands that only read
        pass ``False``: a missing or foreign file is then an error and is
        left untouched.
    """

    def __init__(self, path, create: bool = True):
        self.path = Path(path)
        if not create:
            self._open_existing()
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._db = sqlite3.connect(self.path, timeout=LOCK_WAIT_S, isolation_level=None)
            self._db.row_factory = sqlite3.Row
            self._retry(lambda: self._db.execute("PRAGMA journal_mode=WAL"))
            self._db.execute("PRAGMA synchronous=NORMAL")
            with self._transaction():
                for statement in _SCHEMA.split(";"):
                    if statement.strip():
                        self._db.execute(statement)
        except sqlite3.DatabaseError as exc:
            raise BenchError(f"{self.path}: not a usable results database ({exc})") from None

    def _open_existing(self) -> None:
        if not self.path.is_file():
            raise BenchError(f"{self.path}: no results database (check --db, or run a suite first)")
        try:
            self._db = sqlite3.connect(f"{self.path.resolve().as_uri()}?mode=ro", uri=True, timeout=LOCK_WAIT_S,
                                       isolation_level=None)
            self._db.row_factory = sqlite3.Row
            tables = {r[0] for r in self._db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        except sqlite3.DatabaseError as exc:
            raise BenchError(f"{self.path}: not a usable results database ({exc})") from None
        if not {"runs", "results"} <= tables:
            self._db.close()
            raise BenchError(f"{self.path}: not a tlsbench results database (no runs and results tables)")

    def close(self) -> None:
        """Close the connection."""
        self._db.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @staticmethod
    def _retry(action):
        delay, deadline = 0.05, time.monotonic() + LOCK_WAIT_S
        while True:
            try:
                return action()
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) and "busy" not in str(exc) or time.monotonic() > deadline:
                    raise
                time.sleep(delay)
                delay = min(delay * 2, 1.0)

    @contextmanager
    def _transaction(self):
        """One write transaction, taken with ``BEGIN IMMEDIATE`` (retried while the database is locked)."""
        self._retry(lambda: self._db.execute("BEGIN IMMEDIATE"))
        try:
            yield
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._retry(lambda: self._db.execute("COMMIT"))

    def create_run(self, suite: str, suite_digest: str, config: dict, config_digest: str,
                   commit: str | None = None, notes: dict | None = None) -> str:
        """Record a new run and return its id (``YYYYmmddTHHMMSS-<hex>``).

        Parameters
        ----------
        suite : str
            Suite name.
        suite_digest : str
            Digest of the suite's cases.
        config : dict
            Run configuration (JSON-ready).
        config_digest : str
            Digest of ``config``.
        commit : str or None
            Code commit; ``None`` for the current one.
        notes : dict or None
            JSON-ready notes.

        Returns
        -------
        str
            The new run's id.
        """
        run_id = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S") + "-" + secrets.token_hex(3)
        with self._transaction():
            self._db.execute(
                "INSERT INTO runs (run_id, created, git_commit, machine, suite, suite_digest, config, config_digest,"
                " status, notes) VALUES (?, ?, ?, ?, ?, ?, ?, ?, 'running', ?)",
                (run_id, utc_now(), commit or git_commit(), json.dumps(machine_info()), suite, suite_digest,
                 json.dumps(config, sort_keys=True), config_digest, json.dumps(notes or {})))
        return run_id

    def find_resumable(self, config_digest: str, commit: str) -> str | None:
        """The latest unfinished run with this configuration and code commit, if any.

        Parameters
        ----------
        config_digest : str
            Digest of the run configuration.
        commit : str
            Code commit.

        Returns
        -------
        str or None
            The run's id, or ``None``.
        """
        row = self._db.execute(
            "SELECT run_id FROM runs WHERE status = 'running' AND config_digest = ? AND git_commit = ?"
            " ORDER BY created DESC LIMIT 1", (config_digest, commit)).fetchone()
        return None if row is None else row["run_id"]

    def add_results(self, run_id: str, rows: list[dict]) -> int:
        """Store result rows in one transaction; rows already stored are left alone. Returns rows added.

        Parameters
        ----------
        run_id : str
            The run's id.
        rows : list of dict
            Result rows (metrics in the units of their names).

        Returns
        -------
        int
            Number of rows added.
        """
        values = []
        for row in rows:
            row = {**row, "finished": row.get("finished") or utc_now()}
            values.append((run_id,) + tuple(json.dumps(row[c], sort_keys=True) if c in _JSON_COLUMNS else row.get(c)
                                            for c in _RESULT_COLUMNS))
        with self._transaction():
            before = self._db.total_changes
            self._db.executemany(
                f"INSERT OR IGNORE INTO results (run_id, {', '.join(_RESULT_COLUMNS)}) "
                f"VALUES ({', '.join('?' * (len(_RESULT_COLUMNS) + 1))})", values)
            return self._db.total_changes - before

    def done_pairs(self, run_id: str) -> set[tuple[str, str]]:
        """``(case, variant)`` pairs already stored for a run."""
        rows = self._db.execute("SELECT case_name, variant FROM results WHERE run_id = ?", (run_id,))
        return {(r["case_name"], r["variant"]) for r in rows}

    def finish_run(self, run_id: str) -> None:
        """Mark a run complete."""
        with self._transaction():
            self._db.execute("UPDATE runs SET status = 'complete', finished = ? WHERE run_id = ?", (utc_now(), run_id))

    def set_notes(self, run_id: str, notes: dict) -> None:
        """Replace a run's notes (JSON-ready).

        Parameters
        ----------
        run_id : str
            The run's id.
        notes : dict
            JSON-ready notes.
        """
        with self._transaction():
            self._db.execute("UPDATE runs SET notes = ? WHERE run_id = ?", (json.dumps(notes), run_id))

    def resolve(self, run: str) -> str:
        """A run id from an id, a unique id prefix or ``latest``.

        ``latest`` is the latest suite run; sweep runs (suites named
        ``sweep-*``, which a main job runs after its suite) count only when
        the store holds nothing else.

        Raises
        ------
        BenchError
            If no run (or more than one) matches.
        """
        if run == "latest":
            row = self._db.execute("SELECT run_id FROM runs ORDER BY suite LIKE 'sweep-%', created DESC LIMIT 1"
                                   ).fetchone()
            if row is None:
                raise BenchError(f"{self.path}: the store holds no run yet")
            return row["run_id"]
        matches = [r["run_id"] for r in self._db.execute("SELECT run_id FROM runs WHERE run_id LIKE ? ORDER BY created",
                                                          (run.replace("%", "") + "%",))]
        if len(matches) != 1:
            known = [r["run_id"] for r in self._db.execute("SELECT run_id FROM runs ORDER BY created DESC LIMIT 5")]
            what = "no run" if not matches else f"{len(matches)} runs"
            raise BenchError(f"{self.path}: {what} match {run!r}; latest runs: {known or 'none'} (or use 'latest')")
        return matches[0]

    def run_info(self, run_id: str) -> dict:
        """The ``runs`` row of a run, JSON columns decoded."""
        row = self._db.execute("SELECT * FROM runs WHERE run_id = ?", (run_id,)).fetchone()
        if row is None:
            raise BenchError(f"{self.path}: no run {run_id!r}")
        return _decoded(row)

    def runs(self, suite: str) -> list[dict]:
        """The complete runs of a suite (``runs`` rows, JSON columns decoded), oldest first."""
        rows = self._db.execute("SELECT * FROM runs WHERE suite = ? AND status = 'complete' ORDER BY created",
                                (suite,))
        return [_decoded(r) for r in rows]

    def results(self, run_id: str) -> list[dict]:
        """Every result row of a run, JSON columns decoded, in finishing order."""
        rows = self._db.execute("SELECT * FROM results WHERE run_id = ? ORDER BY finished", (run_id,))
        return [_decoded(r) for r in rows]


def _decoded(row: sqlite3.Row) -> dict:
    return {k: json.loads(row[k]) if k in _JSON_COLUMNS and row[k] is not None else row[k] for k in row.keys()}
