"""A policy node's side of signed weights (docs/ros_graph.md, "Who may change the weights"): it reads the trainer's
announcements, screens each before any byte of the weights travels, fetches an accepted one chunk by chunk from
the trainer's FetchWeights service, checks the bytes against the signed SHA-256 and hands them to the node.

Screening, in order (``security.weights_signing``, ``security.weights_order``): well-formed fields with a non-empty
SHA-256 and a size within the node's bound; a trusted key's valid signature over every field; a network that fits
the node (the caller's ``fits``); newer than the release acting (``ReleaseOrder``: a replay or a rollback needs the
operator's ``~/accept_older_weights`` call first). Everything else is refused, counted by reason and summarised in
the log once per report period, never a line per message.

The fetch never blocks the node: one request at a time through the asynchronous client, its answer filed by the
executor between the node's other callbacks (decisions go on at every period), a steady-clock timer re-sending a
chunk that got no answer (a reply can be lost while DDS matches the server's reply writer) and giving up after
``MAX_TRIES`` failures of a chunk or ``STALL_S`` without progress. While a fetch runs, a newer trusted announcement
waits (the newest one only) and starts as soon as the fetch ends; the trainer keeps the previous release servable
for that time.

A fetch that failed — a file whose hash does not match (a forged server answered first, issue 43), a chunk that
failed ``MAX_TRIES`` times, a stall — is not the end of the release: it is fetched again after a backoff that
doubles from ``BACKOFF_FIRST_S`` up to ``BACKOFF_CAP_S`` (10 s), for as long as it is the newest release announced.
So a process that answers fetches with junk faster than the trainer can delay new weights while it answers, never
make the node drop them: within ``BACKOFF_CAP_S`` plus one fetch of it going quiet the release is taken
(``weights_fetch_restarts``, ``weights_fetch_backoff_s`` in diagnostics).
"""
from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey
from dynenv_msgs.msg import WeightsAnnouncement
from dynenv_msgs.srv import AcceptOlderWeights, FetchWeights
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future

from dynenv_ros.ros.qos import latched
from dynenv_ros.ros.weights_release import from_message
from dynenv_ros.security.weights_download import ChunkRefused, Download
from dynenv_ros.security.weights_order import ReleaseOrder
from dynenv_ros.security.weights_signing import Announcement, Refused, check_fields, verify

# Every reason a release is refused for: the diagnostics keys weights_refused_<reason>.
REASONS = ("malformed", "empty_sha256", "oversized", "untrusted_key", "bad_signature", "wrong_network", "rollback",
           "older_run", "hash_mismatch", "fetch_failed", "load_failed")
CHUNK_TIMEOUT_S = 2.0      # re-send a chunk request unanswered this long
RETRY_DELAY_S = 0.5        # after a refused or malformed answer
MAX_TRIES = 5              # failures of one chunk before this fetch of the file is given up (and started again)
STALL_S = 30.0             # no chunk accepted for this long (the service gone): this fetch given up
BACKOFF_FIRST_S = 0.5      # wait before fetching a release again after a failed fetch; doubles each time …
BACKOFF_CAP_S = 10.0       # … up to this: a starved release is tried at least every 10 s while it is the newest
WATCH_PERIOD_S = 0.2


def backoff_s(failed_attempts: int) -> float:
    """Seconds before fetching a release again after its ``failed_attempts``-th failed fetch: 0.5, 1, 2, 4, 8, then
    10 s for ever (``BACKOFF_CAP_S``)."""
    return min(BACKOFF_CAP_S, BACKOFF_FIRST_S * 2.0 ** (max(1, failed_attempts) - 1))


def newer(a: Announcement, b: Announcement) -> bool:
    """``a`` supersedes ``b``: a higher version of the same run, or a later signed stamp of another run."""
    return a.version > b.version if a.run_id == b.run_id else a.stamp_ns > b.stamp_ns


@dataclass
class _Fetch:
    announcement: Announcement
    download: Download
    attempt: int = 1
    tries: int = 0                     # failures of the current chunk
    future: Future | None = None
    offset: int = 0                    # of the request in flight
    sent: float = 0.0
    retry_at: float = 0.0
    progress_at: float = field(default_factory=time.monotonic)


class WeightsFollower:
    """Announcements in, verified policy bytes out (``install``). Counts go to the node's ``counts``: weights_loaded,
    weights_refused (all reasons) and weights_refused_<reason>, weights_duplicate, weights_other_run,
    weights_superseded, weights_fetch_retries (chunks), weights_fetch_restarts (whole fetches after a failure)."""

    def __init__(self, node: Node, *, topic: str, service: str, accept_service: str,
                 trusted: dict[str, Ed25519PublicKey], max_bytes: int, order: ReleaseOrder,
                 fits: Callable[[str], None], install: Callable[[bytes, Announcement], str],
                 counts: Counter, note: Callable[[str], None], run_filter: str = "",
                 report_period_s: float = 1.0, operator: Any = None) -> None:
        self.node, self.trusted, self.max_bytes, self.order = node, trusted, max_bytes, order
        self.fits, self.install, self.counts, self.note, self.run_filter = fits, install, counts, note, run_filter
        self.fetch: _Fetch | None = None
        self.pending: Announcement | None = None
        # A release whose fetch failed, waiting out its backoff: (announcement, next attempt, due on time.monotonic)
        self.again: tuple[Announcement, int, float] | None = None
        self.last_refusal = ""
        self._reported: Counter[str] = Counter()
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.subscription = node.create_subscription(WeightsAnnouncement, topic, self._on_announcement, latched(1))
        self.client = node.create_client(FetchWeights, service)
        # The operator's door to an older release: only with a gate (ros.operator_gate) that checks signatures.
        self.operator = operator
        self.accept_service = (node.create_service(AcceptOlderWeights, accept_service, self._on_accept_older)
                               if operator is not None else None)
        self.watch_timer = node.create_timer(WATCH_PERIOD_S, self._watch, clock=steady)
        self.report_timer = node.create_timer(report_period_s, self._report, clock=steady)
        if not trusted:
            node.get_logger().warning("no trusted_weights_keys: weights announced by a trainer will be refused "
                                      "(give the node the trainer's public key, e.g. -p "
                                      "trusted_weights_keys:=[~/.config/dynenv_ros/keys/trainer.pub])")
        else:
            node.get_logger().info(f"following signed weights on {topic}; trusted keys {', '.join(sorted(trusted))}")

    # -- screening ------------------------------------------------------------------------------------------------
    def _on_announcement(self, msg: WeightsAnnouncement) -> None:
        announcement = from_message(msg)
        if self.run_filter and announcement.run_id != self.run_filter:
            self.counts["weights_other_run"] += 1
            return
        self.consider(announcement)

    def consider(self, announcement: Announcement) -> None:
        """Screen one announcement; fetch it, queue it behind the fetch running, or refuse it."""
        a = announcement
        fetching = self.fetch.announcement if self.fetch else (self.again[0] if self.again else None)
        if self.order.is_duplicate(a) or (fetching is not None and fetching == a):
            self.counts["weights_duplicate"] += 1
            return
        try:
            check_fields(a, self.max_bytes)
            verify(a, self.trusted)
            try:
                self.fits(a.metadata_json)
            except ValueError as error:
                raise Refused("wrong_network", str(error)) from None
            self.order.check(a)
        except Refused as refusal:
            self.refuse(refusal.reason, f"version {a.version} of run {a.run_id[:40]!r}: {refusal}")
            return
        if fetching is None:
            self._start(a)
        elif self.fetch is None:                     # the waiting release is no longer the newest: drop it
            if newer(a, fetching):
                self.again = None
                self._start(a)
            else:
                self.counts["weights_superseded"] += 1
        elif newer(a, fetching) and (self.pending is None or newer(a, self.pending)):
            self.pending = a
        else:
            self.counts["weights_superseded"] += 1

    def refuse(self, reason: str, text: str) -> None:
        self.counts["weights_refused"] += 1
        self.counts[f"weights_refused_{reason}"] += 1
        self.last_refusal = f"{reason}: {text}"
        self.note(self.last_refusal)

    def _on_accept_older(self, request: AcceptOlderWeights.Request,
                         response: AcceptOlderWeights.Response) -> AcceptOlderWeights.Response:
        refused = self.operator.refusal("accept_older_weights", request)
        if refused is not None:
            response.success, response.reason = False, refused[0]
            response.message = f"refused ({refused[0]}): {refused[1]}"
            return response
        self.order.allow_older_once()
        mark = self.order.mark
        acting = f"version {mark.version} of run {mark.run_id}" if mark else "no trainer release"
        response.success = True
        response.message = f"the next signed release older than {acting} will be accepted, once"
        self.node.get_logger().warning(f"accept_older_weights called: {response.message}")
        return response

    # -- fetching -------------------------------------------------------------------------------------------------
    def _start(self, a: Announcement, attempt: int = 1) -> None:
        self.again = None
        self.fetch = _Fetch(a, Download(a.size, a.sha256), attempt=attempt)
        self._send()

    def _send(self) -> None:
        fetch, now = self.fetch, time.monotonic()
        if not self.client.service_is_ready():
            fetch.retry_at = now + WATCH_PERIOD_S
            return
        offset, length = fetch.download.next_range()
        a = fetch.announcement
        future = self.client.call_async(FetchWeights.Request(run_id=a.run_id, version=a.version, offset=offset,
                                                             length=length))
        fetch.future, fetch.offset, fetch.sent = future, offset, now
        future.add_done_callback(lambda done, mine=fetch: self._on_chunk(mine, done))

    def _on_chunk(self, fetch: _Fetch, future: Future) -> None:
        if fetch is not self.fetch or future is not fetch.future:
            return                                   # an answer to a request given up on
        fetch.future = None
        try:
            response = future.result()
        except Exception as error:                 # noqa: BLE001 - a failed call is one failed try
            self._retry(fetch, f"{type(error).__name__}: {error}")
            return
        if not response.success:
            if self.pending is not None:             # the trainer moved on: take the newer release now
                self._end()
                return
            self._retry(fetch, f"the server said: {response.message}")
            return
        try:
            fetch.download.add(fetch.offset, response.data)
        except ChunkRefused as error:
            self._retry(fetch, str(error))
            return
        fetch.tries, fetch.progress_at = 0, time.monotonic()
        if fetch.download.complete:
            self._complete(fetch)
        else:
            self._send()

    def _retry(self, fetch: _Fetch, why: str) -> None:
        self.counts["weights_fetch_retries"] += 1
        fetch.tries += 1
        if fetch.tries > MAX_TRIES:
            self._fail(fetch, f"chunk at {fetch.offset} failed {fetch.tries} times, last: {why}")
            return
        fetch.retry_at = time.monotonic() + RETRY_DELAY_S

    def _watch(self) -> None:
        """Steady-clock timer: re-send unanswered requests, retry when due, give up a stalled fetch."""
        fetch, now = self.fetch, time.monotonic()
        if fetch is None:
            if self.again is not None and now >= self.again[2]:
                a, attempt, _ = self.again
                self.counts["weights_fetch_restarts"] += 1
                self._start(a, attempt)
            return
        if now - fetch.progress_at > STALL_S:
            self._fail(fetch, f"no chunk for {STALL_S:.0f} s (service {self.client.srv_name} gone or silent)")
            return
        if fetch.future is not None:
            if now - fetch.sent <= CHUNK_TIMEOUT_S:
                return
            self.client.remove_pending_request(fetch.future)
            fetch.future = None
            self._retry(fetch, f"no answer in {CHUNK_TIMEOUT_S:.0f} s")
            if self.fetch is not fetch:
                return
        if now >= fetch.retry_at:
            self._send()

    def _complete(self, fetch: _Fetch) -> None:
        a = fetch.announcement
        try:
            data = fetch.download.finish()
        except Refused as refusal:
            self.refuse(refusal.reason, f"version {a.version} of run {a.run_id[:40]!r}: {refusal}")
            self._end(retry=fetch)
            return
        try:
            digest = self.install(data, a)
        except ValueError as error:
            self.refuse("load_failed", f"version {a.version} of run {a.run_id[:40]!r}: {error}")
            self._end()
            return
        try:
            self.order.accept(a)
        except ValueError as error:                  # the state file could not be written: say so, go on
            self.node.get_logger().error(str(error), throttle_duration_sec=60.0)
        self.counts["weights_loaded"] += 1
        self.node.get_logger().info(f"weights version {a.version} of run {a.run_id} (sha256 {digest[:12]}, key "
                                    f"{a.key_id})", throttle_duration_sec=10.0)
        self._end()

    def _fail(self, fetch: _Fetch, why: str) -> None:
        a = fetch.announcement
        self.refuse("fetch_failed", f"version {a.version} of run {a.run_id[:40]!r}: {why}")
        self._end(retry=fetch)

    def _end(self, retry: _Fetch | None = None) -> None:
        """The fetch is over: drop its buffer, start the release waiting if any; else, when it failed (``retry``),
        fetch the same release again after the backoff — it is still the newest announced."""
        if self.fetch is not None and self.fetch.future is not None:
            self.client.remove_pending_request(self.fetch.future)
        self.fetch, waiting, self.pending = None, self.pending, None
        if waiting is not None:
            self._start(waiting)
        elif retry is not None:
            self.again = (retry.announcement, retry.attempt + 1, time.monotonic() + backoff_s(retry.attempt))

    # -- reporting ------------------------------------------------------------------------------------------------
    def _report(self) -> None:
        """One log line per period with the refusals since the last one, by reason, and the last refusal."""
        new = {r: self.counts[f"weights_refused_{r}"] - self._reported[r] for r in REASONS
               if self.counts[f"weights_refused_{r}"] > self._reported[r]}
        if not new:
            return
        self._reported.update(new)
        self.node.get_logger().warning("trainer weights refused: " + ", ".join(f"{n} {r}" for r, n in new.items())
                                       + f"; last: {self.last_refusal}")

    def diagnostics(self) -> dict[str, Any]:
        fetch, again = self.fetch, self.again
        values = {"weights_trusted_keys": str(len(self.trusted)),
                  "weights_fetching": (f"{fetch.announcement.run_id}/{fetch.announcement.version} "
                                       f"{fetch.download.received}/{fetch.download.size}" if fetch else ""),
                  "weights_fetch_attempt": str(fetch.attempt if fetch else again[1] if again else 0),
                  "weights_fetch_backoff_s": (f"{max(0.0, again[2] - time.monotonic()):.1f}" if again and not fetch
                                              else "0")}
        for key in ("weights_duplicate", "weights_superseded", "weights_fetch_retries", "weights_fetch_restarts"):
            values[key] = str(self.counts.get(key, 0))
        for reason in REASONS:
            values[f"weights_refused_{reason}"] = str(self.counts.get(f"weights_refused_{reason}", 0))
        return values
