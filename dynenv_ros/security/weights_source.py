"""Who released a signed weights announcement and where its bytes come from (issue 43, "fetches that cannot be
starved"): the releasing trainer's node, its FetchWeights service (a name that carries the signing key's id), the
topic its bytes are published on, and the SHA-256 of the chunk manifest — all inside the signed ``metadata_json``
under ``"source"``, so the signature covers them and the message type stays the one every deployed node speaks
(docs/decisions.md).

An announcement without a source (a trainer from before issue 43 item 3) is refused (``no_source``): a node could
only fetch it from an unnamed service any process may answer first, which is what this closes. A source that is not
well formed, or whose fetch service does not carry the signing key's id, is refused as ``bad_source``.
"""
from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass

from dynenv_ros.security.weights_signing import Announcement, Refused

SOURCE_KEY = "source"
_NAME = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+")
_SHA256 = re.compile(r"[0-9a-f]{64}")
MAX_NAME = 256


@dataclass(frozen=True)
class Source:
    """Where a release comes from: ``node`` fully qualified; ``fetch_service`` ends in ``_<key id>``; ``blob_topic``
    empty when the trainer publishes no bytes (the fetch service only); ``manifest_sha256`` hashes the chunks'
    digests (``weights_download.manifest``)."""
    node: str
    fetch_service: str
    blob_topic: str
    manifest_sha256: str


def fetch_service_name(prefix: str, key_id: str) -> str:
    """The trainer's FetchWeights service for a signing key: ``/trainer/fetch_weights`` and ``0123…`` give
    ``/trainer/fetch_weights_0123…`` (a name token may not start with a digit, so the id is a suffix)."""
    return f"{prefix}_{key_id}"


def with_source(metadata_json: str, source: Source) -> str:
    """``metadata_json`` (a JSON object: the network's shape) with the source added, keys sorted."""
    meta = json.loads(metadata_json) if metadata_json else {}
    if not isinstance(meta, dict):
        raise ValueError("metadata_json must be a JSON object to carry the release's source")
    meta[SOURCE_KEY] = asdict(source)
    return json.dumps(meta, sort_keys=True)


def source_of(announcement: Announcement) -> Source:
    """The signed source of a verified announcement; Refused (``no_source``, ``bad_source``) otherwise."""
    a = announcement
    try:
        meta = json.loads(a.metadata_json)
    except ValueError:
        meta = None
    fields = meta.get(SOURCE_KEY) if isinstance(meta, dict) else None
    if fields is None:
        raise Refused("no_source", "the announcement names no source (a trainer from before issue 43: update it; "
                                   "the node fetches only from the trainer that signed the release)")
    try:
        source = Source(**{k: fields[k] for k in ("node", "fetch_service", "blob_topic", "manifest_sha256")})
    except (KeyError, TypeError):
        raise Refused("bad_source", f"source {str(fields)[:120]!r} lacks node, fetch_service, blob_topic or "
                                    "manifest_sha256") from None
    for name, value, may_be_empty in (("node", source.node, False), ("fetch_service", source.fetch_service, False),
                                      ("blob_topic", source.blob_topic, True)):
        if not isinstance(value, str) or len(value) > MAX_NAME or not (
                _NAME.fullmatch(value) or (may_be_empty and value == "")):
            raise Refused("bad_source", f"source {name} {str(value)[:80]!r} is not a fully qualified ROS name")
    if not source.fetch_service.endswith(f"_{a.key_id}"):
        raise Refused("bad_source", f"fetch service {source.fetch_service!r} does not carry the signing key's id "
                                    f"{a.key_id}")
    if not isinstance(source.manifest_sha256, str) or not _SHA256.fullmatch(source.manifest_sha256):
        raise Refused("bad_source", "source manifest_sha256 is not 64 lowercase hex characters")
    return source
