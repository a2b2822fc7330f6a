"""``quadnav-sim soup``: the uniform average of the weights of runs fine-tuned from the same start.

A *model soup* (Wortsman et al., *Model soups*, ICML 2022): runs that start from the same weights
and differ only in their seed (or settings) tend to lie in one basin of the loss, and the mean of
their weights is often a better model than most of them. Averaging is only meaningful there, so
every checkpoint must have the same network, primitives, preprocessing and depth safety filter,
and name the same ``init_model`` (and the same ``init_model_sha256``, where one was pinned) in its
training config; anything else is refused, naming the file and what differs.

The mean is taken in float64 in the order the checkpoints are listed and cast back, so the same
command gives the same weights bit for bit. ``meta["soup_of"]`` lists each ingredient's path,
SHA-256, run name and seed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

__all__ = ["SoupError", "add_parser", "run", "soup"]

class SoupError(ValueError):
    """The checkpoints cannot be averaged into one model."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "soup",
        help="average the weights of runs fine-tuned from the same start (a model soup)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("models", nargs="+", metavar="CKPT", help="two or more checkpoints to average")
    p.add_argument("--out", required=True, help="where to write the averaged checkpoint")
    p.set_defaults(func=run)


def _start(path: str, meta: dict[str, Any]) -> tuple[str, str]:
    train = meta.get("train_config")
    init = train.get("init_model") if isinstance(train, dict) else None
    if not init:
        raise SoupError(
            f"{path}: its meta names no train_config.init_model; a soup averages runs fine-tuned "
            "from the same weights"
        )
    return str(init), str(train.get("init_model_sha256") or "")


def soup(paths: list[str]) -> tuple[Any, dict[str, Any], Any]:
    """Average ``paths``' weights; return (model, meta, first checkpoint) or raise SoupError."""
    import torch

    from quadnav_onboard.checkpoint import load_checkpoint

    if len(paths) < 2:
        raise SoupError(f"a soup needs two or more checkpoints, got {len(paths)}")
    ckpts = [load_checkpoint(p) for p in paths]
    first, first_path = ckpts[0], paths[0]
    seen: dict[str, str] = {}
    for path, ck in zip(paths, ckpts, strict=True):
        if ck.sha256 in seen:
            raise SoupError(f"{path}: the same file as {seen[ck.sha256]} (sha256 {ck.sha256[:12]}…)")
        seen[ck.sha256] = path
    start = _start(first_path, first.meta)
    for path, ck in zip(paths[1:], ckpts[1:], strict=True):
        for section, a, b in (
            ("network", first.network, ck.network),
            ("primitives", first.primitives, ck.primitives),
            ("preprocess", first.preprocess, ck.preprocess),
            ("meta.shield", first.meta.get("shield"), ck.meta.get("shield")),
        ):
            if a != b:
                raise SoupError(f"{path}: its {section} differs from {first_path}'s: {b!r} against {a!r}")
        other = _start(path, ck.meta)
        if other != start:
            raise SoupError(
                f"{path}: started from init_model {other[0]!r} (sha256 {other[1] or 'not pinned'}), "
                f"{first_path} from {start[0]!r} (sha256 {start[1] or 'not pinned'})"
            )
    states = [ck.model.state_dict() for ck in ckpts]
    mean = {}
    for key, tensor in states[0].items():
        total = torch.zeros_like(tensor, dtype=torch.float64)
        for state in states:
            total += state[key].to(torch.float64)
        mean[key] = (total / len(states)).to(tensor.dtype)
    model = first.model
    model.load_state_dict(mean, strict=True)
    meta: dict[str, Any] = {
        "shield": first.meta.get("shield"),
        "init_model": start[0],
        "init_model_sha256": start[1],
        "soup_of": [
            {
                "path": str(path),
                "sha256": ck.sha256,
                "name": (ck.meta.get("train_config") or {}).get("name", ""),
                "seed": ck.meta.get("seed"),
            }
            for path, ck in zip(paths, ckpts, strict=True)
        ],
    }
    if meta["shield"] is None:
        del meta["shield"]
    return model, meta, first


def run(args: argparse.Namespace) -> int:
    from quadnav_onboard.checkpoint import CheckpointError, save_checkpoint

    out_path = Path(args.out).resolve()
    for path in args.models:
        if Path(path).resolve() == out_path:
            print(f"quadnav-sim soup: --out {args.out} is one of the checkpoints to average", file=sys.stderr)
            return 2
    try:
        model, meta, first = soup(list(args.models))
    except (CheckpointError, SoupError) as exc:
        print(f"quadnav-sim soup: {exc}", file=sys.stderr)
        return 2
    out = save_checkpoint(
        Path(args.out), model, primitives=first.primitives, preprocess=first.preprocess, meta=meta
    )
    print(f"wrote {out} (the mean of {len(args.models)} checkpoints' weights)")
    return 0
