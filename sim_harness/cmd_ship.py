"""``quadnav-sim ship``: a trained checkpoint, with the shield it flies with, as a shippable model.

The weights are copied unchanged; ``meta["shield"]`` records the depth safety filter
(:class:`quadnav_onboard.shield.ShieldConfig`) that evaluation and the flight daemon then apply
with this model, and ``meta["shipped_from"]`` the source file and its SHA-256.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "ship",
        help="write a checkpoint with the shield it flies with (weights unchanged)",
        description="Copy a checkpoint's weights and record the depth safety filter it flies with.",
    )
    p.add_argument("--model", required=True, help="trained checkpoint (e.g. runs/<run>/checkpoints/final.pt)")
    p.add_argument("--out", required=True, help="where to write the shippable checkpoint")
    p.add_argument("--shield", choices=("on", "off"), default="on", help="depth safety filter (default on)")
    p.add_argument("--clearance-m", type=float, default=None, help="shield clearance (m; default 0.5)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from quadnav_onboard.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
    from quadnav_onboard.shield import ShieldConfig

    try:
        ckpt = load_checkpoint(args.model)
        shield = ShieldConfig(enabled=args.shield == "on")
        if args.clearance_m is not None:
            shield = dataclasses.replace(shield, clearance_m=args.clearance_m)
    except (CheckpointError, ValueError) as exc:
        print(f"quadnav-sim ship: {exc}", file=sys.stderr)
        return 2
    meta = dict(ckpt.meta)
    meta["shield"] = dataclasses.asdict(shield)
    meta["shipped_from"] = {"path": str(args.model), "sha256": ckpt.sha256}
    out = save_checkpoint(
        Path(args.out), ckpt.model, primitives=ckpt.primitives, preprocess=ckpt.preprocess, meta=meta
    )
    print(f"wrote {out} (shield {'on' if shield.enabled else 'off'}, weights of {args.model})")
    return 0
