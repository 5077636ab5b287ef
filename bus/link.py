"""A fake bus between sans-IO endpoints, for tests without sockets (docs/style.md: h11).

Frames take the full path (encode, E2E protect, classify, assemble) with a fixed latency in
the caller's time, and can be dropped or corrupted by a hook, so the protocol machines and
the receiver are tested together deterministically.

    link = FakeLink(latency_s=0.001)
    plant, flight = link.endpoint("plant"), link.endpoint("flight")
    plant.send(Sync(0, 0), now_s=0.0)
    flight.deliver(now_s=0.002)   # -> [(Sync(0, 0), 0.001)]
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from bus.catalog import CATALOG
from bus.codec import Frame, Message, encode
from bus.e2e import Protector
from bus.receiver import Receiver

FrameHook = Callable[[str, Frame], Frame | None]  # (sender, frame) -> frame to deliver or None


@dataclass
class Endpoint:
    name: str
    link: FakeLink
    receiver: Receiver = field(default_factory=Receiver)
    protector: Protector = field(default_factory=Protector)
    inbox: list[Frame] = field(default_factory=list)
    tx_frames: int = 0

    def send(self, msg: Message, now_s: float) -> None:
        for fr in encode(msg):
            data = self.protector.protect(CATALOG.by_id[fr.arbitration_id].data_id, fr.data)
            self.send_frame(Frame(fr.arbitration_id, data), now_s)

    def send_frame(self, fr: Frame, now_s: float) -> None:
        self.tx_frames += 1
        if self.link.hook is not None:
            fr = self.link.hook(self.name, fr)
            if fr is None:
                return
        stamped = Frame(
            fr.arbitration_id, fr.data, fr.is_fd, fr.is_extended_id, now_s + self.link.latency_s
        )
        for ep in self.link.endpoints.values():
            if ep is not self:
                ep.inbox.append(stamped)

    def deliver(self, now_s: float) -> list[tuple[Message, float]]:
        """Classify the frames that have arrived by ``now_s``; complete valid messages."""
        due = [f for f in self.inbox if f.timestamp_s <= now_s]
        self.inbox = [f for f in self.inbox if f.timestamp_s > now_s]
        out = []
        for fr in due:
            v = self.receiver.classify(fr, now_s)
            if v.message is not None:
                out.append((v.message, v.rx_time_s))
        self.receiver.expire(now_s)
        return out


@dataclass
class FakeLink:
    latency_s: float = 0.0
    hook: FrameHook | None = None
    endpoints: dict[str, Endpoint] = field(default_factory=dict)

    def endpoint(self, name: str) -> Endpoint:
        ep = Endpoint(name, self)
        self.endpoints[name] = ep
        return ep
