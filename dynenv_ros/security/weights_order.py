"""Which signed weights release may replace the one acting: only a newer one, so a recorded genuine announcement
replayed later, or a trainer's older weights, cannot roll a robot back.

The high-water mark is the last release accepted: (run, version, signed stamp, sha256). A release of the same run
must have a strictly greater version; one of another run a strictly later signed stamp (versions of two runs are
not comparable; the stamp is signed, so a replay cannot move it forward). The same release again is a duplicate
(a transient-local topic hands it out again on every new match), not a refusal. ``allow_older_once`` — an
operator's explicit call — lets the one release it names (run and version) through once, though it fails this order
(a deliberate rollback, or a trainer restarted from an older checkpoint). It names the release so that a process
replaying some other recorded genuine release at the same moment cannot choose which one is taken.

With a ``state_file`` the mark survives a restart of the node (a small JSON file, replaced atomically on each
acceptance); without one a restarted node accepts the first trusted release it sees.
"""
from __future__ import annotations

import json
import os
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

from dynenv_ros.security.weights_signing import Announcement, Refused


@dataclass(frozen=True)
class Mark:
    """The last release accepted."""
    run_id: str
    version: int
    stamp_ns: int
    sha256: str

    @classmethod
    def of(cls, announcement: Announcement) -> "Mark":
        return cls(announcement.run_id, announcement.version, announcement.stamp_ns, announcement.sha256)


class ReleaseOrder:
    """The mark, the one-shot allowance, and the optional state file."""

    def __init__(self, state_file: str | os.PathLike[str] | None = None) -> None:
        self.state_file = Path(state_file).expanduser() if state_file else None
        self.mark: Mark | None = self._load() if self.state_file else None
        self.older_allowed: tuple[str, int] | None = None      # (run, version) an operator let through, once

    def is_duplicate(self, announcement: Announcement) -> bool:
        """The release acting already (same run, version and bytes)."""
        return self.mark is not None and Mark.of(announcement) == self.mark

    def check(self, announcement: Announcement) -> None:
        """Refused (``rollback``, ``older_run``) unless newer than the mark or the release an operator named;
        consumes the one-shot allowance when it lets that release through."""
        problem = self._problem(announcement)
        if problem is None:
            return
        if self.older_allowed == (announcement.run_id, announcement.version):
            self.older_allowed = None
            return
        raise Refused(*problem)

    def _problem(self, a: Announcement) -> tuple[str, str] | None:
        mark = self.mark
        if mark is None:
            return None
        if a.run_id == mark.run_id:
            if a.version > mark.version:
                return None
            return ("rollback", f"version {a.version} of run {a.run_id} is not newer than version {mark.version} "
                                "acting (an operator's signed call of ~/accept_older_weights naming it allows it once)")
        if a.stamp_ns > mark.stamp_ns:
            return None
        return ("older_run", f"run {a.run_id} was signed at {a.stamp_ns / 1e9:.3f}, not after run {mark.run_id}'s "
                             f"version {mark.version} acting ({mark.stamp_ns / 1e9:.3f}; call "
                             f"~/accept_older_weights, signed by an operator, with run_id {a.run_id} and version "
                             f"{a.version} to allow it once)")

    def allow_older_once(self, run_id: str, version: int) -> None:
        """Let version ``version`` of run ``run_id`` through once (replaces an allowance not yet used)."""
        self.older_allowed = (run_id, version)

    def accept(self, announcement: Announcement) -> None:
        """The release now acting: the new mark, also written to the state file when there is one (ValueError if
        that write fails; the mark in memory is the new one all the same)."""
        self.mark = Mark.of(announcement)
        if self.state_file is not None:
            self._save(self.mark)

    def _load(self) -> Mark | None:
        path = self.state_file
        if not path.exists():
            return None
        try:
            fields = json.loads(path.read_text())
            mark = Mark(str(fields["run_id"]), int(fields["version"]), int(fields["stamp_ns"]),
                        str(fields["sha256"]))
        except (OSError, ValueError, KeyError, TypeError) as error:
            raise ValueError(f"weights state file {path} cannot be read ({type(error).__name__}: {error}); "
                             "remove it to start without a high-water mark") from None
        return mark

    def _save(self, mark: Mark) -> None:
        path = self.state_file
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
            with os.fdopen(fd, "w") as handle:
                json.dump(asdict(mark), handle)
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(temporary, path)
        except OSError as error:
            raise ValueError(f"cannot write weights state file {path}: {error.strerror or error}") from None
