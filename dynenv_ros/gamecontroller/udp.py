"""The GameController on the wire (issue 41; docs/interfaces.md, "The GameController on UDP"): the simulated game's
RoboCupGameControlData packets sent over UDP, the robots' RoboCupGameControlReturnData packets read back. ROS-free.

The real GameController broadcasts "RGme" on port 3838 twice a second and reads "RGrt" on port 3939. ``GameControllerLink``
does the same for the simulator: ``send`` one packet to ``(host, port)`` (a broadcast address needs ``broadcast``),
``receive`` every return packet waiting on the return port without blocking. A return packet that is not one
(``packet.decode_return_data``: wrong length, header, version, player number, fallen flag, a value that is not
finite) is refused and counted by its one-word reason, and the link keeps listening; at most ``MAX_PACKETS_PER_CALL``
are read per call, so a flood cannot hold the simulator.
"""
from __future__ import annotations

import socket
from collections import Counter

from dynenv_ros.gamecontroller import packet as gc

MAX_PACKETS_PER_CALL = 64


class GameControllerLink:
    """A UDP sender of RGme packets and, with ``return_port`` ≥ 0, a reader of RGrt packets (module docstring)."""

    def __init__(self, host: str, port: int, return_port: int = -1, broadcast: bool = False,
                 counts: Counter[str] | None = None) -> None:
        if not 1 <= port <= 65535 or not -1 <= return_port <= 65535:
            raise ValueError(f"ports must be in 1 … 65535 (return port: -1 off, 0 any free), got {port}, {return_port}")
        self.target = (host, port)
        self.counts: Counter[str] = Counter() if counts is None else counts
        self.latest: dict[tuple[int, int], gc.ReturnData] = {}    # (team, player) -> its newest return packet
        self.sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        if broadcast:
            self.sender.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        self.receiver: socket.socket | None = None
        try:
            if return_port >= 0:
                self.receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                self.receiver.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self.receiver.bind(("", return_port))
                self.receiver.setblocking(False)
        except OSError:
            self.close()
            raise

    @property
    def return_port(self) -> int | None:
        """The port return packets are read on (the one bound, when 0 asked for any), None when off."""
        return None if self.receiver is None else int(self.receiver.getsockname()[1])

    def send(self, data: gc.GameControlData) -> bytes:
        """Encode and send one packet (``packet.PacketError`` for content the packet cannot hold); returns it."""
        packet = gc.encode_game_control_data(data)
        try:
            self.sender.sendto(packet, self.target)
            self.counts["gc_packets_sent"] += 1
        except OSError:
            self.counts["gc_send_failed"] += 1
        return packet

    def receive(self) -> list[gc.ReturnData]:
        """The well-formed return packets waiting (at most ``MAX_PACKETS_PER_CALL``), each also kept in ``latest``."""
        if self.receiver is None:
            return []
        out = []
        for _ in range(MAX_PACKETS_PER_CALL):
            try:
                packet = self.receiver.recv(gc.GAMECONTROLLER_RETURN_STRUCT_SIZE + 1)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self.counts["gc_return_failed"] += 1
                break
            try:
                data = gc.decode_return_data(packet)
            except gc.PacketError as error:
                self.counts[f"gc_return_refused_{error.reason}"] += 1
                continue
            self.counts["gc_return_accepted"] += 1
            self.latest[(data.team_num, data.player_num)] = data
            out.append(data)
        return out

    def close(self) -> None:
        self.sender.close()
        if self.receiver is not None:
            self.receiver.close()


__all__ = ["MAX_PACKETS_PER_CALL", "GameControllerLink"]
