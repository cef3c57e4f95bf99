"""Readers for the tests of cdro-foxglove and cdro-export, written from the published specs and
independent of the code under test (which writes through foxglove-sdk and mcap-ros2-support):

- a Foxglove WebSocket client (github.com/foxglove/ws-protocol/blob/main/docs/spec.md, subprotocol
  `foxglove.websocket.v1`; foxglove-sdk's server names the same protocol `foxglove.sdk.v1` and
  accepts only that name, so the client offers both): JSON text messages `serverInfo`, `advertise` (channels with `id`,
  `topic`, `encoding`, `schemaName`, `schema`, `schemaEncoding`); the client sends `subscribe`
  (`subscriptions`: `id`, `channelId`); message data arrive as binary frames: opcode 0x01,
  uint32 LE subscription id, uint64 LE receive time (ns), payload;
- protobuf payloads decoded with google.protobuf from the FileDescriptorSet the schema carries
  (base64 on the WebSocket, raw bytes in MCAP);
- ROS 2 CDR payloads decoded with rosbags' type store.
"""
from __future__ import annotations

import base64
import json
import struct
import time

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.json_format import MessageToDict

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]   # one protocol, two names
OP_MESSAGE_DATA = 0x01


def protobuf_class(schema_name: str, descriptor_set: bytes):
    files = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set).file
    pool = descriptor_pool.DescriptorPool()
    added: set[str] = set()
    pending = list(files)
    while pending:  # dependencies first, whatever the order in the set
        ready = [f for f in pending if all(d in added for d in f.dependency)]
        assert ready, f"{schema_name}: unresolvable dependencies in its descriptor set"
        for f in ready:
            pool.Add(f)
            added.add(f.name)
            pending.remove(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def decode_protobuf(cls, payload: bytes) -> dict:
    return MessageToDict(cls.FromString(payload), preserving_proto_field_name=True,
                         always_print_fields_with_no_presence=True)


class FoxgloveClient:
    """A blocking client: connect, read the advertisements, subscribe, collect messages."""

    def __init__(self, url: str, guard_s: float):
        from websockets.sync.client import connect

        # No keepalive pings: a test that reads nothing for a while would see its pong queued behind
        # the data and the connection closed.
        self.connection = connect(url, subprotocols=SUBPROTOCOLS, open_timeout=guard_s, max_size=None,
                                  ping_interval=None).__enter__()  # closed by close()
        assert self.connection.subprotocol in SUBPROTOCOLS
        self.server_info: dict | None = None
        self.channels: dict[int, dict] = {}          # channel id -> advertised channel
        self.subscriptions: dict[int, int] = {}      # subscription id -> channel id
        self.decoders: dict[int, object] = {}
        self.messages: list[tuple[str, int, object]] = []   # (topic, receive time ns, decoded)

    def _handle(self, frame) -> None:
        if isinstance(frame, str):
            message = json.loads(frame)
            if message["op"] == "serverInfo":
                self.server_info = message
            elif message["op"] == "advertise":
                for channel in message["channels"]:
                    self.channels[channel["id"]] = channel
            elif message["op"] == "unadvertise":
                for channel_id in message["channelIds"]:
                    self.channels.pop(channel_id, None)
            return
        assert frame[0] == OP_MESSAGE_DATA, f"binary opcode {frame[0]:#x}"
        subscription, receive_ns = struct.unpack_from("<IQ", frame, 1)
        channel = self.channels[self.subscriptions[subscription]]
        payload = bytes(frame[13:])
        if channel["encoding"] == "protobuf":
            decoded = decode_protobuf(self.decoders[subscription], payload)
        else:
            assert channel["encoding"] == "json", channel
            decoded = json.loads(payload)
        self.messages.append((channel["topic"], receive_ns, decoded))

    def pump(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            try:
                frame = self.connection.recv(timeout=left)
            except TimeoutError:
                return
            self._handle(frame)

    def wait_for(self, predicate, what: str, guard_s: float):
        end = time.monotonic() + guard_s
        while time.monotonic() < end:
            value = predicate()
            if value:
                return value
            self.pump(0.2)
        topics = sorted(c["topic"] for c in self.channels.values())
        raise AssertionError(f"timed out waiting for {what}; advertised {topics}, {len(self.messages)} message(s)")

    def subscribe_all(self) -> None:
        subscriptions = []
        for channel_id, channel in self.channels.items():
            if channel_id in self.subscriptions.values():
                continue
            subscription = len(self.subscriptions) + 1
            self.subscriptions[subscription] = channel_id
            if channel["encoding"] == "protobuf":
                assert channel["schemaEncoding"] == "protobuf", channel
                self.decoders[subscription] = protobuf_class(channel["schemaName"], base64.b64decode(channel["schema"]))
            subscriptions.append({"id": subscription, "channelId": channel_id})
        if subscriptions:
            self.connection.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def of_topic(self, topic: str) -> list:
        return [decoded for t, _, decoded in self.messages if t == topic]

    def close(self) -> None:
        self.connection.close()


def read_mcap(path) -> tuple[str, list[tuple[str, str, str, int, object]]]:
    """(profile, [(topic, schema name, schema encoding, log time ns, decoded)]) of an MCAP file:
    protobuf and JSON decoded here, ROS 2 CDR with rosbags."""
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    classes: dict[int, object] = {}
    out = []
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        profile = reader.get_header().profile
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if schema.encoding == "protobuf":
                if schema.id not in classes:
                    classes[schema.id] = protobuf_class(schema.name, schema.data)
                decoded = decode_protobuf(classes[schema.id], message.data)
            elif channel.message_encoding == "json":
                decoded = json.loads(message.data)
            elif channel.message_encoding == "cdr":
                assert schema.encoding == "ros2msg", schema
                decoded = store.deserialize_cdr(message.data, schema.name)
            else:
                raise AssertionError(f"{channel.topic}: encoding {channel.message_encoding}")
            out.append((channel.topic, schema.name, schema.encoding, message.log_time, decoded))
    return profile, out
