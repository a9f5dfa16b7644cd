"""A Foxglove WebSocket client for the tests of the live view (test/view): the protocol by hand with ``websockets``.

The client offers the subprotocols ``foxglove.sdk.v1`` (what the foxglove-sdk server of this version accepts)
and ``foxglove.websocket.v1`` (the ws-protocol's name, docs/spec.md of foxglove/ws-protocol), reads the server's
``serverInfo`` and ``advertise`` JSON messages, sends ``subscribe`` with ids of its own, and decodes the binary
Message Data frames: opcode 0x01, uint32 subscription id, uint64 receive time (little-endian), the payload.
"""
from __future__ import annotations

import asyncio
import json
import socket
import struct
from dataclasses import dataclass, field
from typing import Any

from websockets.asyncio.client import ClientConnection, connect

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01
_HEADER = struct.Struct("<IQ")


@dataclass
class Client:
    """One connection: the channels advertised so far and the messages received per topic, in order."""

    ws: ClientConnection
    info: dict[str, Any] = field(default_factory=dict)
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Topic -> its channel as advertised (``id``, ``encoding``, ``schemaName``, ``schema``...)."""
    received: dict[str, list[Any]] = field(default_factory=dict)
    """Topic -> the payloads received (JSON channels decoded), in order."""
    _topic_of: dict[int, str] = field(default_factory=dict)

    async def read_advertised(self, topics: set[str], timeout: float = 30.0) -> None:
        """Read the server's messages until ``serverInfo`` and an advertisement of every topic of ``topics``."""
        async with asyncio.timeout(timeout):
            while not self.info or not topics <= set(self.channels):
                await self._handle(await self.ws.recv())

    async def subscribe(self, topics: list[str]) -> None:
        """Subscribe to ``topics`` (subscription ids: their index in the client's subscriptions)."""
        subscriptions = []
        for topic in topics:
            sub_id = len(self._topic_of)
            self._topic_of[sub_id] = topic
            self.received.setdefault(topic, [])
            subscriptions.append({"id": sub_id, "channelId": self.channels[topic]["id"]})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    async def read_one(self) -> None:
        """Receive and file one message of the server."""
        await self._handle(await self.ws.recv())

    async def read_until(self, done: Any, timeout: float) -> None:
        """Receive until ``done()`` holds; ``TimeoutError`` after ``timeout`` seconds."""
        async with asyncio.timeout(timeout):
            while not done():
                await self.read_one()

    async def _handle(self, frame: str | bytes) -> None:
        if isinstance(frame, str):
            message = json.loads(frame)
            if message["op"] == "serverInfo":
                self.info = message
            elif message["op"] == "advertise":
                self.channels |= {c["topic"]: c for c in message["channels"]}
            return
        assert frame[0] == MESSAGE_DATA, frame[:1]
        sub_id, _ = _HEADER.unpack_from(frame, 1)
        topic = self._topic_of[sub_id]
        payload = frame[1 + _HEADER.size:]
        self.received[topic].append(json.loads(payload) if self.channels[topic]["encoding"] == "json" else payload)


async def open_client(port: int, receive_buffer: int = 0, max_queue: int = 16) -> Client:
    """Connect to the view on 127.0.0.1:``port``; ``receive_buffer``: the socket's SO_RCVBUF in bytes (0: the
    system's), ``max_queue``: frames the library buffers before it stops reading the socket."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if receive_buffer:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
    sock.setblocking(False)
    await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", port))
    ws = await connect(f"ws://127.0.0.1:{port}", sock=sock, subprotocols=SUBPROTOCOLS, max_queue=max_queue,
                       ping_interval=None, open_timeout=30)
    assert ws.subprotocol in SUBPROTOCOLS
    return Client(ws)
