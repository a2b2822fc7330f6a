"""Write docs/configuration.md, the configuration reference, from the config dataclasses.

    .venv/bin/python scripts/gen_config_reference.py            # rewrite docs/configuration.md
    .venv/bin/python scripts/gen_config_reference.py --check    # exit 1 if it differs from the code
    .venv/bin/python scripts/gen_config_reference.py --yaml     # the flight config's defaults, commented

Two trees: the flight config (``quadnav_onboard.daemon.config.FlightConfig``, what
``quadnav-onboard --config FILE`` reads) and the training config
(``sim_harness.rl.config.TrainConfig``, what ``quadnav-sim train --recipe FILE`` reads). A config
field without a docstring stops the script with the class and field named.
tests/test_config_reference.py checks that the committed file is what this script writes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "docs" / "configuration.md"

HEADER = """\
# Configuration reference

Every key of the flight config and of the training config, with its type and range, default,
unit and meaning. This file is generated from the config dataclasses (the docstring under each
field is the key's meaning): `python scripts/gen_config_reference.py` writes it, and
tests/test_config_reference.py fails when it no longer matches the code. Do not edit it by hand.

A config file is YAML; a key left out takes its default, an unknown key, a wrong type, NaN, ±inf
or a value outside the stated range is refused with the file, the key and the value named.
`quadnav-onboard --print-config` (or `python scripts/gen_config_reference.py --yaml`) prints the
flight config's defaults as a commented
YAML to start a file from (it loads back into the defaults). Ranges: `[a, b]` includes both ends,
`(a, b]` excludes `a`.
"""

FLIGHT_INTRO = """\
What `quadnav-onboard --config FILE` flies (`config/flight.yaml` is the paper's lab,
`config/sim.yaml` the dry run). Positions are world frame (x forward, y left, z up), metres.
`mission.waypoints_m` is required for a flight."""

TRAIN_INTRO = """\
What `quadnav-sim train` trains: every key is also a flag (`--episodes 2000`), and a recipe file
(`quadnav-sim train --recipe recipes/paper.yaml`, see docs/training.md) holds any of these keys.
One more key, `base: OTHER.yaml` (a path relative to the file), starts from every key of another
recipe file, the file's own keys overriding them (`recipes/privileged-lab-hinge.yaml` is
`recipes/privileged-lab.yaml` and one key). The defaults are the paper's recipe; each run
directory's `config.json` holds every key, bases resolved."""


def document() -> str:
    """The reference, as the code defines it today."""
    from quadnav_onboard.config_reference import markdown_reference
    from quadnav_onboard.daemon.config import FlightConfig
    from sim_harness.rl.config import TrainConfig

    return markdown_reference(
        [
            ("The flight config", FlightConfig, FLIGHT_INTRO),
            ("The training config (recipes)", TrainConfig, TRAIN_INTRO),
        ],
        HEADER,
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--check", action="store_true", help="exit 1 if the file differs from the code")
    p.add_argument(
        "--yaml", action="store_true", help="print the flight config's defaults as a commented YAML"
    )
    p.add_argument("--out", type=Path, default=OUT, help=f"where to write (default: {OUT.relative_to(REPO)})")
    args = p.parse_args(argv)
    from quadnav_onboard.config_reference import MissingDocstringError

    try:
        if args.yaml:
            from quadnav_onboard.config_reference import flight_config_yaml

            sys.stdout.write(flight_config_yaml())
            return 0
        text = document()
    except MissingDocstringError as exc:
        print(f"gen_config_reference: {exc}", file=sys.stderr)
        return 2
    if args.check:
        current = args.out.read_text(encoding="utf-8") if args.out.is_file() else ""
        if current != text:
            print(f"{args.out}: out of date; run: python scripts/gen_config_reference.py", file=sys.stderr)
            return 1
        print(f"{args.out}: up to date")
        return 0
    args.out.write_text(text, encoding="utf-8")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
