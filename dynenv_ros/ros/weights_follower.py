"""A policy node's side of signed weights (docs/ros_graph.md, "Who may change the weights"): it reads the trainer's
announcements, screens each before any byte of the weights travels, takes the bytes of an accepted one from the
trainer's blob topic or, as a fallback, its fetch service, checks them against the signed digests and hands them to
the node.

Screening, in order (``security.weights_signing``, ``security.weights_source``, ``security.weights_order``):
well-formed fields with a non-empty SHA-256 and a size within the node's bound; a trusted key's valid signature
over every field; a signed source (``no_source``, ``bad_source``): the releasing trainer's node, its fetch service
(whose name carries the key id), its blob topic and the digest of the chunk manifest; a network that fits the node
(the caller's ``fits``); newer than the release acting (``ReleaseOrder``: a replay or a rollback needs the
operator's ``~/accept_older_weights`` call first). Everything else is refused, counted by reason and summarised in
the log once per report period, never a line per message.

Two routes fill one buffer of the announced size (``security.weights_download``), and either may finish it:

- **The blob topic** (issue 43, "fetches that cannot be starved"). The trainer publishes each release's manifest
  and chunks on ``<trainer>/weights_blob`` (reliable, transient local). The node (re)subscribes when a release
  starts, with a reader deep enough for all of its samples, so the trainer's writer hands it the release it holds
  whole even while the executor is busy; it places each sample by its SHA-256: the manifest by the signed digest, a
  chunk by the manifest. Anything else — another process's junk, another release's chunk — is refused and counted
  (``weights_blob_refused_<reason>``) and cannot displace a genuine sample: every sample is checked, nothing is
  overwritten. A ROS service client takes the first answer from any
  server of the name; a topic reader takes every sample, so a faster attacker cannot starve this route. Without
  progress for ``BLOB_REDELIVER_S`` the node subscribes again (``weights_blob_resubscribes``): the trainer's
  writer hands the release out again, and chunks already verified are kept.
- **The fetch service** the signed source names, one chunk at a time through the asynchronous client (answers
  filed by the executor between decisions), after ``BLOB_GRACE_S`` without blob progress, or at once when the
  trainer publishes no blob. A steady-clock timer re-sends a chunk unanswered for ``CHUNK_TIMEOUT_S``; an attempt
  is given up after ``MAX_TRIES`` failures of a chunk, ``STALL_S`` without progress, or a chunk (or file) that is
  not the signed one (``hash_mismatch``: a forged server answered first), and started again after a backoff that
  doubles from ``BACKOFF_FIRST_S`` up to ``BACKOFF_CAP_S`` (10 s), for as long as the release is the newest. The
  nodes serving that name are shown (``weights_fetch_servers``) so an impostor is visible.

While a service attempt runs, a newer trusted announcement waits (the newest one only) and starts when the attempt
ends; otherwise it replaces the release wanted at once (the trainer keeps the previous release servable meanwhile).
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
from dynenv_ros.ros.weights_release import BLOB_READER_DEPTH, from_message
from dynenv_ros.security.weights_download import ChunkRefused, Download, SampleRefused
from dynenv_ros.security.weights_order import ReleaseOrder
from dynenv_ros.security.weights_signing import Announcement, Refused, check_fields, verify
from dynenv_ros.security.weights_source import Source, source_of

# Every reason a release is refused for: the diagnostics keys weights_refused_<reason>.
REASONS = ("malformed", "empty_sha256", "oversized", "untrusted_key", "bad_signature", "no_source", "bad_source",
           "wrong_network", "rollback", "older_run", "hash_mismatch", "fetch_failed", "load_failed")
# Why a blob sample was refused: weights_blob_refused_<reason> (security.weights_download.SampleRefused).
BLOB_REASONS = ("oversized", "unverifiable", "unmatched")
ROUTES = ("blob", "fetch", "both")      # which route delivered a release: weights_loaded_via_<route>
CHUNK_TIMEOUT_S = 2.0      # re-send a chunk request unanswered this long
RETRY_DELAY_S = 0.5        # after a refused or malformed answer
MAX_TRIES = 5              # failures of one chunk before this fetch attempt is given up (and started again)
STALL_S = 30.0             # no chunk accepted for this long (the service gone): this attempt given up
BACKOFF_FIRST_S = 0.5      # wait before a fetch attempt after a failed one; doubles each time …
BACKOFF_CAP_S = 10.0       # … up to this: a starved release is tried at least every 10 s while it is the newest
BLOB_GRACE_S = 2.0         # the blob route this long without progress: the fetch service is asked too
BLOB_REDELIVER_S = 5.0     # the blob route this long without progress: subscribe again (the writer resends)
WATCH_PERIOD_S = 0.2


def backoff_s(failed_attempts: int) -> float:
    """Seconds before fetching a release again after its ``failed_attempts``-th failed fetch: 0.5, 1, 2, 4, 8, then
    10 s for ever (``BACKOFF_CAP_S``)."""
    return min(BACKOFF_CAP_S, BACKOFF_FIRST_S * 2.0 ** (max(1, failed_attempts) - 1))


def newer(a: Announcement, b: Announcement) -> bool:
    """``a`` supersedes ``b``: a higher version of the same run, or a later signed stamp of another run."""
    return a.version > b.version if a.run_id == b.run_id else a.stamp_ns > b.stamp_ns


@dataclass
class _Release:
    """The release wanted: its buffer, and the state of each route."""
    announcement: Announcement
    source: Source
    download: Download
    blob: bool                          # the trainer publishes its bytes on the topic this node reads
    blob_progress_at: float = field(default_factory=time.monotonic)     # the release's start, or the last sample placed
    blob_subscribed_at: float = field(default_factory=time.monotonic)   # the last (re)subscription
    routes: set[str] = field(default_factory=set)                       # which routes brought verified bytes
    # the fetch service
    attempt: int = 0                    # attempts started
    running: bool = False               # an attempt runs
    again_at: float = 0.0               # no attempt before this (the backoff after a failed one)
    tries: int = 0                      # failures of the current chunk
    future: Future | None = None
    offset: int = 0                     # of the request in flight
    sent: float = 0.0
    retry_at: float = 0.0
    progress_at: float = 0.0


class WeightsFollower:
    """Announcements in, verified policy bytes out (``install``). Counts go to the node's ``counts``: weights_loaded,
    weights_loaded_via_<route>, weights_refused (all reasons) and weights_refused_<reason>, weights_duplicate,
    weights_other_run, weights_superseded, weights_fetch_retries (chunks), weights_fetch_restarts (attempts after a
    failure), weights_fetch_chunks, weights_blob_chunks, weights_blob_duplicate, weights_blob_unwanted,
    weights_blob_refused and weights_blob_refused_<reason>, weights_blob_resubscribes."""

    stall_s = STALL_S       # an instance may be given a shorter stall bound (test_policy_weights.py's stall test)

    def __init__(self, node: Node, *, topic: str, blob_topic: str, accept_service: str,
                 trusted: dict[str, Ed25519PublicKey], max_bytes: int, order: ReleaseOrder,
                 fits: Callable[[str], None], install: Callable[[bytes, Announcement], str],
                 counts: Counter, note: Callable[[str], None], run_filter: str = "",
                 report_period_s: float = 1.0, operator: Any = None) -> None:
        self.node, self.trusted, self.max_bytes, self.order = node, trusted, max_bytes, order
        self.fits, self.install, self.counts, self.note, self.run_filter = fits, install, counts, note, run_filter
        self.wanted: _Release | None = None
        self.pending: Announcement | None = None
        # The newest trusted release refused only for its order (rollback, older_run): an operator who names it in
        # ~/accept_older_weights gets it at once, without waiting for the trainer to announce it again.
        self.refused_older: dict[tuple[str, int], Announcement] = {}
        self.last_refusal = ""
        self.last_route = ""
        self.last_source = ""
        self.fetch_servers = ""
        self._reported: Counter[str] = Counter()
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.subscription = node.create_subscription(WeightsAnnouncement, topic, self._on_announcement, latched(1))
        self.blob_topic_name = blob_topic
        self.blob_subscription = self._subscribe_blob()
        self.blob_topic = self.blob_subscription.topic_name          # resolved, as a signed source names it
        self.client: Any = None
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
            node.get_logger().info(f"following signed weights on {topic} (bytes on {self.blob_topic}); trusted "
                                   f"keys {', '.join(sorted(trusted))}")

    # -- screening ------------------------------------------------------------------------------------------------
    def _on_announcement(self, msg: WeightsAnnouncement) -> None:
        announcement = from_message(msg)
        if self.run_filter and announcement.run_id != self.run_filter:
            self.counts["weights_other_run"] += 1
            return
        self.consider(announcement)

    def consider(self, announcement: Announcement) -> None:
        """Screen one announcement; take it now, queue it behind the fetch attempt running, or refuse it."""
        a, wanted = announcement, self.wanted
        if self.order.is_duplicate(a) or a in (wanted.announcement if wanted else None, self.pending):
            self.counts["weights_duplicate"] += 1
            return
        try:
            check_fields(a, self.max_bytes)
            verify(a, self.trusted)
            source = source_of(a)
            try:
                self.fits(a.metadata_json)
            except ValueError as error:
                raise Refused("wrong_network", str(error)) from None
            self.order.check(a)
        except Refused as refusal:
            if refusal.reason in ("rollback", "older_run"):
                self.refused_older = {(a.run_id, a.version): a, **dict(list(self.refused_older.items())[:15])}
            self.refuse(refusal.reason, f"version {a.version} of run {a.run_id[:40]!r}: {refusal}")
            return
        if wanted is None:
            self._start(a, source)
        elif not newer(a, wanted.announcement) or (self.pending is not None and not newer(a, self.pending)):
            self.counts["weights_superseded"] += 1
        elif wanted.running:                          # a fetch attempt runs: the newer one waits for its end
            self.pending = a
        else:                                         # the release wanted is no longer the newest: drop it
            self._start(a, source)

    def refuse(self, reason: str, text: str) -> None:
        self.counts["weights_refused"] += 1
        self.counts[f"weights_refused_{reason}"] += 1
        self.last_refusal = f"{reason}: {text}"
        self.note(self.last_refusal)

    def _on_accept_older(self, request: AcceptOlderWeights.Request,
                         response: AcceptOlderWeights.Response) -> AcceptOlderWeights.Response:
        refused = self.operator.refusal("accept_older_weights", request)
        if refused is None and not request.run_id:
            refused = ("release_unnamed", "name the release to let through: run_id and version, as the refusal of "
                                          "it says ('version 3 of run r1')")
        if refused is not None:
            response.success, response.reason = False, refused[0]
            response.message = f"refused ({refused[0]}): {refused[1]}"
            return response
        self.order.allow_older_once(request.run_id, int(request.version))
        mark = self.order.mark
        acting = f"version {mark.version} of run {mark.run_id}" if mark else "no trainer release"
        response.success = True
        response.message = (f"version {request.version} of run {request.run_id} will be accepted once, though not "
                            f"newer than {acting}; no other older release")
        self.node.get_logger().warning(f"accept_older_weights called: {response.message}")
        named = self.refused_older.pop((request.run_id, int(request.version)), None)
        if named is not None:                       # already announced and refused: take it now
            self.consider(named)
        return response

    # -- the release wanted ---------------------------------------------------------------------------------------
    def _start(self, a: Announcement, source: Source | None = None) -> None:
        self._drop_request()
        source = source if source is not None else source_of(a)
        release = _Release(a, source, Download(a.size, a.sha256, source.manifest_sha256),
                           blob=bool(source.blob_topic) and source.blob_topic == self.blob_topic)
        self.wanted, self.pending, self.last_source = release, None, source.node
        if release.blob:             # a new reader: the trainer's writer hands it the release it holds
            self._resubscribe()
        else:
            self._begin_attempt(release)

    def _finish(self, release: _Release) -> None:
        """Every chunk is held: check the file, install it, or fetch the unverified chunks again."""
        a = release.announcement
        try:
            data = release.download.finish()
        except Refused as refusal:
            self._fail(release, refusal.reason, str(refusal))
            return
        self._drop_request()
        self.wanted = None
        try:
            digest = self.install(data, a)
        except ValueError as error:
            self.refuse("load_failed", f"version {a.version} of run {a.run_id[:40]!r}: {error}")
            self._take_pending()
            return
        try:
            self.order.accept(a)
        except ValueError as error:                  # the state file could not be written: say so, go on
            self.node.get_logger().error(str(error), throttle_duration_sec=60.0)
        route = "both" if len(release.routes) > 1 else next(iter(release.routes), "fetch")
        self.last_route = route
        self.counts["weights_loaded"] += 1
        self.counts[f"weights_loaded_via_{route}"] += 1
        self.node.get_logger().info(f"weights version {a.version} of run {a.run_id} (sha256 {digest[:12]}, key "
                                    f"{a.key_id}, from {release.source.node} by {route})",
                                    throttle_duration_sec=10.0)
        self._take_pending()

    def _take_pending(self) -> None:
        waiting, self.pending = self.pending, None
        if waiting is not None:
            self._start(waiting)

    # -- the blob topic -------------------------------------------------------------------------------------------
    def _subscribe_blob(self, depth: int = BLOB_READER_DEPTH) -> Any:
        return self.node.create_subscription(FetchWeights.Response, self.blob_topic_name, self._on_blob,
                                             latched(depth))

    def _resubscribe(self) -> None:
        """A new reader of the blob topic, so the trainer's transient-local writer hands out what it holds again.
        Deep enough for the whole release wanted (manifest and chunks): the writer hands them out in one burst, and
        a reader that kept fewer would lose the same ones on every resubscription while the executor is busy."""
        release = self.wanted
        samples = release.download.chunks + (release.download.chunks > 1) if release is not None else 0
        self.node.destroy_subscription(self.blob_subscription)
        self.blob_subscription = self._subscribe_blob(max(BLOB_READER_DEPTH, samples))
        if release is not None:
            release.blob_subscribed_at = time.monotonic()

    def _on_blob(self, msg: FetchWeights.Response) -> None:
        release = self.wanted
        if release is None or not release.blob:
            self.counts["weights_blob_unwanted"] += 1
            return
        download, dropped = release.download, release.download.dropped
        try:
            placed = download.offer(memoryview(msg.data))
        except SampleRefused as refusal:
            self.counts["weights_blob_refused"] += 1
            self.counts[f"weights_blob_refused_{refusal.reason}"] += 1
            return
        if placed == "duplicate":
            self.counts["weights_blob_duplicate"] += 1
            return
        self.counts["weights_blob_chunks"] += 1
        release.blob_progress_at = time.monotonic()
        release.routes.add("blob")
        if download.dropped > dropped:               # the manifest showed fetched chunks to be junk
            self._fail(release, "hash_mismatch", f"{download.dropped - dropped} fetched chunk(s) are not the "
                                                 "signed ones (a forged server answered first)")
            if self.wanted is not release:
                return
        if download.complete:
            self._finish(release)

    # -- the fetch service ----------------------------------------------------------------------------------------
    def _client_for(self, service: str) -> Any:
        if self.client is None or self.client.srv_name != service:
            if self.client is not None:
                self.node.destroy_client(self.client)
            self.client = self.node.create_client(FetchWeights, service)
        return self.client

    def _begin_attempt(self, release: _Release) -> None:
        if release.attempt:
            self.counts["weights_fetch_restarts"] += 1
        release.attempt += 1
        release.running, release.tries = True, 0
        release.progress_at = release.retry_at = time.monotonic()
        self._client_for(release.source.fetch_service)
        self.fetch_servers = self._servers(release.source.fetch_service)
        self._send(release)

    def _servers(self, service: str) -> str:
        """The nodes serving ``service`` now (ROS graph), for the diagnostics: more than the trainer named means an
        impostor (or a second trainer sharing a key)."""
        names = []
        for name, namespace in self.node.get_node_names_and_namespaces():
            try:
                served = self.node.get_service_names_and_types_by_node(name, namespace)
            except Exception:                       # noqa: BLE001 - a node gone between the two calls
                continue
            if any(s == service for s, _ in served):
                names.append(f"{namespace.rstrip('/')}/{name}")
        return ", ".join(sorted(names))

    def _send(self, release: _Release) -> None:
        now = time.monotonic()
        if not self.client.service_is_ready():
            release.retry_at = now + WATCH_PERIOD_S
            return
        offset, length = release.download.next_range()
        a = release.announcement
        future = self.client.call_async(FetchWeights.Request(run_id=a.run_id, version=a.version, offset=offset,
                                                             length=length))
        release.future, release.offset, release.sent = future, offset, now
        future.add_done_callback(lambda done, mine=release: self._on_chunk(mine, done))

    def _on_chunk(self, release: _Release, future: Future) -> None:
        if release is not self.wanted or future is not release.future:
            return                                   # an answer to a request given up on
        release.future = None
        try:
            response = future.result()
        except Exception as error:                 # noqa: BLE001 - a failed call is one failed try
            self._retry(release, f"{type(error).__name__}: {error}")
            return
        if not response.success:
            if self.pending is not None:             # the trainer moved on: take the newer release now
                self._start(self.pending)
                return
            self._retry(release, f"the server said: {response.message}")
            return
        if release.download.holds(release.offset):  # the blob route brought that chunk meanwhile
            self._send(release)
            return
        try:
            release.download.add(release.offset, memoryview(response.data))
        except ChunkRefused as error:
            self._retry(release, str(error))
            return
        except Refused as refusal:
            self._fail(release, refusal.reason, str(refusal))
            return
        self.counts["weights_fetch_chunks"] += 1
        release.routes.add("fetch")
        release.tries, release.progress_at = 0, time.monotonic()
        if release.download.complete:
            self._finish(release)
        else:
            self._send(release)

    def _retry(self, release: _Release, why: str) -> None:
        self.counts["weights_fetch_retries"] += 1
        release.tries += 1
        if release.tries > MAX_TRIES:
            self._fail(release, "fetch_failed", f"chunk at {release.offset} failed {release.tries} times, last: "
                                                f"{why}")
            return
        release.retry_at = time.monotonic() + RETRY_DELAY_S

    def _fail(self, release: _Release, reason: str, why: str) -> None:
        """A fetch attempt failed (or the file did not match): refused with the reason; the release stays wanted
        — the blob route goes on, the service is asked again after the backoff — unless a newer one waits."""
        a = release.announcement
        self.refuse(reason, f"version {a.version} of run {a.run_id[:40]!r}: {why}")
        if self.pending is not None:
            self._start(self.pending)
            return
        self._end_attempt(release, failed=True)

    def _end_attempt(self, release: _Release, failed: bool) -> None:
        self._drop_request()
        release.running = False
        if failed:
            release.again_at = time.monotonic() + backoff_s(release.attempt)

    def _drop_request(self) -> None:
        release = self.wanted
        if release is not None and release.future is not None and self.client is not None:
            self.client.remove_pending_request(release.future)
            release.future = None

    def _watch(self) -> None:
        """Steady-clock timer: the blob route's grace and redelivery, the fetch attempt's re-sends, retries, stall
        and backoff."""
        release, now = self.wanted, time.monotonic()
        if release is None:
            return
        blob_quiet = now - release.blob_progress_at
        if release.blob and now - max(release.blob_progress_at, release.blob_subscribed_at) > BLOB_REDELIVER_S:
            self.counts["weights_blob_resubscribes"] += 1
            self._resubscribe()
        if not release.running:
            if (not release.blob or blob_quiet > BLOB_GRACE_S) and now >= release.again_at:
                self._begin_attempt(release)
            return
        if now - release.progress_at > self.stall_s:
            self._fail(release, "fetch_failed", f"no chunk for {self.stall_s:.0f} s (service "
                                                f"{release.source.fetch_service} gone or silent)")
            return
        if release.future is not None:
            if now - release.sent <= CHUNK_TIMEOUT_S:
                return
            self._drop_request()
            self._retry(release, f"no answer in {CHUNK_TIMEOUT_S:.0f} s")
            if self.wanted is not release or not release.running:
                return
        if now >= release.retry_at:
            self._send(release)

    # -- reporting ------------------------------------------------------------------------------------------------
    def _report(self) -> None:
        """One log line per period with the refusals since the last one, by reason, and the last refusal."""
        keys = [f"weights_refused_{r}" for r in REASONS] + [f"weights_blob_refused_{r}" for r in BLOB_REASONS]
        new = {k: self.counts[k] - self._reported[k] for k in keys if self.counts[k] > self._reported[k]}
        if not new:
            return
        self._reported.update(new)
        self.node.get_logger().warning("trainer weights refused: " + ", ".join(
            f"{n} {k.removeprefix('weights_refused_').replace('weights_blob_refused_', 'blob sample ')}"
            for k, n in new.items()) + (f"; last: {self.last_refusal}" if self.last_refusal else ""))

    def diagnostics(self) -> dict[str, Any]:
        release, now = self.wanted, time.monotonic()
        download = release.download if release else None
        values = {"weights_trusted_keys": str(len(self.trusted)),
                  "weights_fetching": (f"{release.announcement.run_id}/{release.announcement.version} "
                                       f"{download.received}/{download.size}" if release and download else ""),
                  "weights_source": self.last_source, "weights_route": self.last_route,
                  "weights_fetch_servers": self.fetch_servers,
                  "weights_fetch_attempt": str(release.attempt if release else 0),
                  "weights_fetch_backoff_s": (f"{max(0.0, release.again_at - now):.1f}"
                                              if release and not release.running and release.attempt else "0")}
        for key in ("weights_duplicate", "weights_superseded", "weights_fetch_retries", "weights_fetch_restarts",
                    "weights_fetch_chunks", "weights_blob_chunks", "weights_blob_duplicate", "weights_blob_unwanted",
                    "weights_blob_refused", "weights_blob_resubscribes",
                    *(f"weights_loaded_via_{r}" for r in ROUTES), *(f"weights_blob_refused_{r}" for r in BLOB_REASONS),
                    *(f"weights_refused_{r}" for r in REASONS)):
            values[key] = str(self.counts.get(key, 0))
        return values
