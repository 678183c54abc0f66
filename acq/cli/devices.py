"""`acq devices`: what this machine has attached that a rig uses; --reset a USB device."""

from __future__ import annotations

import argparse

from acq import json_text

HELP = "list attached scanners, cameras, serial ports, CAN interfaces"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    devices = sub.add_parser(
        "devices",
        help=HELP,
        description="List what this machine has attached that a rig uses: USB devices by "
        "vendor and product, serial ports with their stable /dev/serial/by-id names, V4L2 "
        "cameras, CAN interfaces; each with the configuration line to paste.",
    )
    devices.add_argument("--json", action="store_true", help="JSON instead of text")
    devices.add_argument(
        "--reset", metavar="BUS:ADDR", help="reset a wedged USB device (e.g. 001:004)"
    )
    devices.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """0 done; a reset that fails is a ResetError (1), a bad address an InputError (2)."""
    from acq.record import devices

    if args.reset is not None:
        done = devices.reset(args.reset)
        print(
            json_text.dumps({"reset": done}, indent=None)
            if args.json
            else f"reset USB device {done}"
        )
        return 0
    found = devices.list_devices()
    print(devices.devices_json(found) if args.json else devices.format_devices(found))
    return 0
