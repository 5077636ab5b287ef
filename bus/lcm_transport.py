"""The LCM transport: a ``Port`` whose wire is LCM instead of CAN (docs/lcm.md).

``LcmPort`` has the interface of ``bus.transport.Port`` (``send``, ``send_frame``, ``poll``,
``protect``, ``counts``, ``close``, the same clock) and is a subclass of it, so the plant,
the flight and the fault panel run over it unchanged. A message is encoded and E2E-protected
into its CAN frames exactly as on CAN; the frames of one set then travel as one typed LCM
struct (``bus.lcm_schema``) on the set's channel. A receiver rebuilds the frames from the
struct and gives them to the same ``bus.receiver.Receiver``. Bytes that are not a struct of
the channel (wrong fingerprint, short, wrong E2E block) are counted as ``malformed`` events,
never raised.

``send_frame`` takes single frames too (tests send corrupted ones): frames of a set are held
until the set's last frame, then published as one struct; a frame of a set index already
held publishes nothing for the held partial set (it is dropped and counted in ``tx_errors``,
as a CAN controller would lose a frame) and starts a new one.

Own messages. LCM's UDP multicast loops every message back to its sender: as for python-can's
``udp_multicast``, the port remembers what it published and drops the first equal message
received.

Providers: any LCM URL. ``udpm://`` needs a multicast route (``hil.netns`` gives the processes
a private network namespace that has one); ``memq://`` works within one process (tests).
"""

from __future__ import annotations

import collections
import select
import time

import can

from bus.codec import Frame
from bus.e2e import Protector
from bus.errors import BusError
from bus.lcm_schema import (
    StructDef,
    by_set,
    decode_struct,
    encode_struct,
    to_fields,
    to_frames,
)
from bus.receiver import Receiver, Verdict
from bus.transport import BusLogger, Port, to_can_message

DEFAULT_URL = "udpm://239.255.76.67:7667?ttl=0"


def open_lcm(url: str = DEFAULT_URL):
    """An ``lcm.LCM`` on ``url``; BusError (one line) when it cannot be opened."""
    import lcm

    try:
        return lcm.LCM(url)
    except (OSError, RuntimeError, ValueError) as exc:
        hint = ("; udpm needs a multicast route: `hil run --bus lcm` makes a private network "
                "namespace with one" if url.startswith("udpm") else "")
        raise BusError(f"bus: cannot open lcm {url}: {exc}{hint}") from exc


class _LcmBus:
    """What ``Port`` expects of ``self.bus`` for the attributes it reads (no python-can)."""

    channel = ""

    def __init__(self, lc, url: str) -> None:
        self.lc = lc
        self.url = url

    def shutdown(self) -> None:
        self.lc = None


class LcmPort(Port):
    """A node's port on an LCM bus (see the module doc)."""

    def __init__(self, url: str = DEFAULT_URL, receiver: Receiver | None = None,
                 logger: BusLogger | None = None, lc=None):
        self.url = url
        self.lc = lc if lc is not None else open_lcm(url)
        super().__init__(_LcmBus(self.lc, url), receiver=receiver, logger=logger)
        self._raw = None
        self._echo = None
        self.protector = Protector()
        self._by_set = by_set(self.receiver.catalog)
        self._by_channel = {st.channel: st for st in self._by_set.values()}
        self._held: dict[str, list[Frame]] = {}
        self._sent: collections.deque[tuple[str, bytes]] = collections.deque(maxlen=4096)
        self._inbox: list[tuple[str, bytes, float]] = []
        self.tx_bytes = 0
        self.rx_bytes = 0
        self.malformed = 0
        # Only the catalog's channels (telemetry and other programs' channels stay unread).
        names = "|".join(sorted(self._by_channel))
        self._sub = self.lc.subscribe(f"^({names})$", self._on_message)

    # --- send ------------------------------------------------------------------------

    def _set_of(self, fr: Frame) -> StructDef | None:
        f = self.receiver.catalog.by_id.get(fr.arbitration_id)
        if f is None:
            return None
        return self._by_set.get(f.set_name or f.name)

    def _put(self, fr: Frame) -> bool:
        """Hold ``fr`` until its set is whole, then publish the set as one struct."""
        st = self._set_of(fr)
        if st is None:  # not a catalog frame: LCM has no channel for it
            self.tx_errors += 1
            return False
        index = [f.frame_id for f in st.frames].index(fr.arbitration_id)
        held = self._held.setdefault(st.set_name, [])
        if len(held) != index:
            # Out of set order (a repeat, or a set cut short): the partial set is lost.
            self.tx_errors += len(held)
            held.clear()
            if index != 0:
                self.tx_errors += 1
                return False
        held.append(fr)
        if len(held) < len(st.frames):
            return True
        frames = list(held)
        held.clear()
        data = encode_struct(st, to_fields(st, frames))
        channel = st.channel
        try:
            self.lc.publish(channel, data)
        except (OSError, RuntimeError) as exc:
            self.tx_errors += len(frames)
            self.receiver.events.append(Verdict("internal", detail=f"lcm: publish: {exc}"))
            return False
        self._sent.append((channel, data))
        self.tx_frames += len(frames)
        self.tx_bytes += len(data)
        if self.logger:
            t = time.time()
            for f in frames:
                self.logger.log(to_can_message(f, t))
        return True

    def send(self, *msgs) -> int:
        frames = self.frames_to_send(msgs)  # with the authenticators (bus.secoc)
        if self.send_hook is not None:
            frames = self.send_hook(frames)
        before = self.tx_frames
        for fr in frames:
            self._put(fr)
        return self.tx_frames - before

    # --- receive -----------------------------------------------------------------------

    def _on_message(self, channel: str, data: bytes) -> None:
        self._inbox.append((channel, bytes(data), time.time()))

    def _drain_python_can(self, timeout_s: float,
                          got: list[tuple[Frame, can.Message | None]],
                          limit: int | None = None) -> None:
        """Read what LCM has and turn each message into its set's frames; with ``limit``,
        whole messages up to about that many frames, the rest kept for the next poll."""
        fd = self.lc.fileno()
        timeout = max(0.0, timeout_s)
        while True:
            ready, _, _ = select.select([fd], [], [], timeout)
            if not ready:
                break
            self.lc.handle()
            timeout = 0.0
        inbox, self._inbox = self._inbox, []
        for k, (channel, data, rx) in enumerate(inbox):
            if limit is not None and len(got) >= limit:
                self._inbox = inbox[k:] + self._inbox
                break
            if (channel, data) in self._sent:
                self._sent.remove((channel, data))  # our own message, looped back
                self.echoes_dropped += 1
                continue
            self.rx_bytes += len(data)
            st = self._by_channel.get(channel)
            if st is None:
                continue  # another application's channel under HIL_*: not ours
            try:
                frames = to_frames(st, decode_struct(st, data), rx)
            except (ValueError, KeyError, TypeError, OverflowError) as exc:
                self.malformed += 1  # counted with the frames of the wrong length
                self.receiver._record(
                    Verdict("wrong_length", st.set_name,
                            detail=f"lcm: {channel}: expected a {st.name}, got {len(data)} "
                            f"bytes that do not decode ({exc})", rx_time_s=rx))
                continue
            for fr in frames:
                got.append((fr, to_can_message(fr, rx) if self.logger else None))

    def counts(self) -> dict[str, int]:
        out = super().counts()
        out.update(lcm_tx_bytes=self.tx_bytes, lcm_rx_bytes=self.rx_bytes,
                   lcm_malformed=self.malformed)
        return out

    def close(self) -> None:
        if self.logger:
            self.logger.close()
        if self.lc is not None and self._sub is not None:
            self.lc.unsubscribe(self._sub)
            self._sub = None
        self.bus.shutdown()
