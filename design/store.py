"""The append-only record of a search: one JSON line per evaluation, keyed by its hash.

Written by the client as results arrive (flushed and synced per batch), so a search that
is interrupted, or loses a worker, keeps every evaluation it received, and the next run on
the same folder evaluates only what is missing. The first line names the problem (the
targets' digest): a folder of other targets is refused rather than mixed. A last line cut
short by a crash is removed when the record is opened again.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

from design.objectives import Evaluation
from toggle.params import ParameterError

FILE = "evaluations.jsonl"


class Store:
    """Evaluations of one problem in ``folder``/evaluations.jsonl."""

    def __init__(self, folder: str | Path, digest: str) -> None:
        self.path = Path(folder) / FILE
        self.digest = digest
        self._known: dict[str, Evaluation] = {}
        if self.path.exists():
            self._read()

    def _read(self) -> None:
        raw = self.path.read_bytes()
        if raw and not raw.endswith(b"\n"):  # cut short by a crash: drop the partial line
            raw = raw[:raw.rfind(b"\n") + 1]
            with self.path.open("r+b") as f:
                f.truncate(len(raw))
        lines = raw.decode("utf-8").splitlines()
        try:
            head = json.loads(lines[0]) if lines else {}
        except json.JSONDecodeError:
            head = {}
        if head.get("digest") != self.digest:
            raise ParameterError(
                f"{self.path} holds the evaluations of other targets (or is not a search "
                "record): give another --out folder, or delete it to start afresh")
        for line in lines[1:]:
            try:
                record = json.loads(line)
            except json.JSONDecodeError:  # a damaged line: evaluated again
                continue
            self._known[record["key"]] = Evaluation.from_record(record)

    def __contains__(self, key: str) -> bool:
        return key in self._known

    def get(self, key: str) -> Evaluation:
        return self._known[key]

    def append(self, evaluations: Iterable[Evaluation]) -> None:
        self._write([e for e in evaluations if e.key not in self._known])

    def supersede(self, evaluations: Iterable[Evaluation]) -> None:
        """Record later evaluations of known candidates (more measures: a front design's
        planned duty): their lines follow the first and win when the record is read."""
        self._write(list(evaluations))

    def _write(self, new: list[Evaluation]) -> None:
        if not new:
            return
        if not self.path.exists():  # created with the first result: a refused run leaves none
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.path.write_text(json.dumps({"digest": self.digest}) + "\n", encoding="utf-8")
        with self.path.open("a", encoding="utf-8") as f:
            for e in new:
                f.write(json.dumps(e.as_record(), allow_nan=True) + "\n")
            f.flush()
            os.fsync(f.fileno())
        self._known.update((e.key, e) for e in new)
