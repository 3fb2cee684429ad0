"""Run the EPOS twin alone behind an slcan adapter, without the simulated car.

    python -m viena.services.steering.simulator --port 5010

Then `viena-steering --interface slcan --channel socket://127.0.0.1:5010` drives it, and
any other slcan client (a bus monitor) may listen on the same port.
"""
from __future__ import annotations

import argparse
import logging

from viena.common.signals import stop_on_signals
from viena.services.steering.simulator import TwinSettings, start_twin_on_hub


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m viena.services.steering.simulator", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=0, help="TCP port of the slcan adapter (0 = any)")
    p.add_argument("--no-sweep", action="store_true", help="do not turn the wheel lock to lock")
    p.add_argument("--sweep-speed-qc-s", type=float, default=TwinSettings.sweep_speed_qc_s)
    p.add_argument("--log-level", default="INFO")
    args = p.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(levelname)-7s %(name)s: %(message)s")
    logging.getLogger("canopen").setLevel(max(logging.WARNING, logging.getLogger().level))
    stop = stop_on_signals()
    device = start_twin_on_hub(TwinSettings(sweep=not args.no_sweep, sweep_speed_qc_s=args.sweep_speed_qc_s),
                               host=args.host, port=args.port)
    print(device.url, flush=True)
    stop.wait()
    device.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
