"""``hil record --from-lcm-log LOG``: the recording (``run.rrd``) and the per-tick JSON lines
rebuilt from a run's LCM telemetry log, played by LCM's own ``lcm-logplayer`` (docs/lcm.md,
``hil.lcm_replay``).

The replay runs in a private network namespace with its own multicast route (``hil.netns``),
as ``hil run --bus lcm`` does, so no other LCM program hears it and the host's routes stay
untouched.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hil.argtypes import number
from hil.errors import UsageError
from hil.lcm_replay import PACE_MSG_S


def replay_url(args) -> str:
    from bus.lcm_transport import DEFAULT_URL

    return args.lcm_url or DEFAULT_URL


def _cmd(args) -> int:
    from hil.lcm_replay import count_log, replay, write_records
    from hil.netns import run_in_namespace
    from hil.recorder import build_rrd

    log = Path(args.from_lcm_log).resolve()
    count_log(log)  # a missing or empty log is a one-line error before the namespace
    out = Path(args.out).resolve() if args.out else log.parent / "replay"
    if out == log.parent:
        raise UsageError(f"record: --out {out}: expected a folder other than the log's run "
                         f"folder (its own plant.jsonl / flight.jsonl would be replaced), got "
                         f"that folder")
    url = replay_url(args)
    argv = ["record", "--from-lcm-log", str(log), "--out", str(out), "--lcm-url", url]
    rc = run_in_namespace(argv + (["--speed", repr(args.speed)] if args.speed else []), url)
    if rc is not None:
        return rc
    recs = replay(log, url, speed=args.speed)
    write_records(recs, out)
    rrd = build_rrd(out, recording_id=log.parent.name)
    print(f"record: {len(recs.plant)} plant and {len(recs.flight)} flight records from "
          f"{recs.how}; wrote {out / 'plant.jsonl'}, {out / 'flight.jsonl'}, {rrd}")
    return 0


def register(sub) -> None:
    summary = "rebuild run.rrd and the per-tick records from an LCM log (lcm-logplayer)"
    p = sub.add_parser("record", help=summary, description=summary,
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog="""examples:
  hil run S000-stuck --lcm-log --out runs/a
  hil record --from-lcm-log runs/a/run.lcmlog          writes runs/a/replay/run.rrd

The log is played with lcm-logplayer in a private network namespace; what arrives is
counted against the log, and a loss is an error (lower --speed).""")
    p.add_argument("--from-lcm-log", required=True, metavar="LOG",
                   help="an LCM log with HIL_TRUTH / HIL_FLIGHT_VIEW (hil run --lcm-log)")
    p.add_argument("--out", metavar="DIR",
                   help="output folder (default: replay/ beside the log)")
    p.add_argument("--speed", type=number(gt=0, le=10000), metavar="X",
                   help=f"lcm-logplayer's speed multiplier (default: paced to about "
                        f"{PACE_MSG_S:g} messages per second)")
    p.add_argument("--lcm-url", metavar="URL",
                   help="LCM provider to play on (default udpm://239.255.76.67:7667?ttl=0, "
                        "in a private network namespace)")
    p.set_defaults(func=_cmd)
