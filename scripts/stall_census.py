#!/usr/bin/env python3
"""What a model does in the flights that end short of the goal without a crash: the decisions
of every flight of an eval that ended at the step limit or the deviation limit, counted by what
the filter allowed and what the DQN chose.

The flights are those of ``quadnav-sim eval`` with the same flags (same worlds, seeds and
filter). Each decision of such a flight falls in one of four classes:

- ``forward``: it flew a primitive that moves forward (one of the 9 with a forward component);
- ``held_back``: it flew one that does not, though the filter allowed a forward one and did not
  overrule the DQN's first choice: the DQN itself chose to hold;
- ``overruled_back``: it flew one that does not, a forward one being allowed, because the filter
  vetoed the DQN's first choice and the DQN ranked a non-forward one next;
- ``boxed_in``: the filter allowed no forward primitive. Of these, it also counts those where
  the filter, had it seen the true geometry (``sim_harness.route.true_geometry_verdict``: the
  same predicted paths, clearance and known space), would have allowed one: boxed in by its view.

With ``--teacher-recipe RECIPE`` the privileged teacher that labels that training recipe's
paper-world DAgger task at the flights' scale (``sim_harness.rl.train.privileged_teacher``)
labels every ``held_back`` state too, and the census counts those where it would have flown
forward: a student holding back where its teacher goes on has not learned the teacher's choice
there. A recipe with the filter teacher, and flights under a flight config (whose lab task has a
teacher of its own), are refused.

Trace development worlds, never the test set (procedural seed 4242) when choosing anything.

Usage:  python scripts/stall_census.py [--model CKPT] [--world W ... | --procedural N --procedural-seed P]
            [--primitive-scale M | --flight-config FLIGHT.yaml [--layouts N --layout-seed S]]
            [--trials 10] [--seed 0]
            [--shield on|model] [--teacher-recipe RECIPE] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter

import numpy as np

CLASSES = ("forward", "held_back", "overruled_back", "boxed_in")
HELD_BACK = CLASSES.index("held_back")


def classify(q: np.ndarray, allowed: np.ndarray, forward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(flown (N,), class index (N,) into :data:`CLASSES`) for Q-values ``q`` (N, A), the filter's
    ``allowed`` (N, A) and ``forward`` (A,): which primitives move forward."""
    from quadnav_onboard.policy import masked_argmax

    flown = masked_argmax(q, allowed)
    first = np.argmax(q, axis=1)
    fwd_allowed = (allowed & forward[None, :]).any(axis=1)
    cls = np.where(
        forward[flown], 0, np.where(~fwd_allowed, 3, np.where(first == flown, 1, 2))
    )
    return flown, cls


def census(policy, worlds, trials: int, seed: int, env_cfg, limits=None, depth_noise=None,
           teacher=None) -> dict:
    """Fly the eval's flights (under a flight config: its ``limits`` and ``depth_noise``, as
    ``quadnav-sim eval --flight-config`` flies them); count the classes of each outcome's decisions.
    With ``teacher`` (a :class:`~sim_harness.rl.teacher.Teacher`), also count the held-back
    decisions where it would have flown a forward primitive."""
    from sim_harness.rl.evaluate import evaluate
    from sim_harness.rl.imitation import holding_primitives
    from sim_harness.route import true_geometry_verdict

    forward = ~holding_primitives(env_cfg.primitives)
    chosen: list[np.ndarray] = []  # the classes of the batch the policy just chose for
    decisions: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []  # world, trials, class, open
    taught: list[tuple[int, np.ndarray]] = []  # world, the held-back trials the teacher flies forward in
    world_no = [0]

    def act(depth, rel, allowed):
        q = policy.q_values_batch(depth, rel, env_cfg.primitives.scale_m)
        flown, cls = classify(q, np.asarray(allowed, dtype=bool), forward)
        chosen[:] = [cls]
        return flown

    def looks(world, env, depth, rel, actions) -> None:  # once per step, after act: the running flights
        running = np.flatnonzero(~env.done)
        opened = (true_geometry_verdict(env, running)[0] & forward[None, :]).any(axis=1)
        decisions.append((world_no[0], running, chosen[0][running], opened))
        held = running[chosen[0][running] == HELD_BACK]
        if teacher is not None and held.size:
            taught.append((world_no[0], held[forward[teacher.labels(env, held)]]))

    def next_world(_w) -> None:
        world_no[0] += 1

    rows = evaluate(act, worlds, trials, seed, env_cfg, on_world_done=next_world,
                    limits=limits, depth_noise=depth_noise, on_step=looks)
    counts: dict[str, Counter] = {}
    boxed_by_view: Counter = Counter()
    for w, running, cls, opened in decisions:
        for t, k, o in zip(running.tolist(), cls.tolist(), opened.tolist(), strict=True):
            outcome = rows[w * trials + t].outcome
            counts.setdefault(outcome, Counter())[CLASSES[k]] += 1
            boxed_by_view[outcome] += int(k == 3 and o)
    failures = Counter(r.world for r in rows if r.outcome not in ("goal", "crash"))
    outcomes = Counter(r.outcome for r in rows)
    out = {
        "flights": len(rows),
        "outcomes": dict(outcomes),
        "decisions": {o: {k: int(c[k]) for k in CLASSES} for o, c in sorted(counts.items())},
        "boxed_in_by_the_view": {o: int(boxed_by_view[o]) for o in sorted(counts)},
        "failures_by_world": dict(failures.most_common()),
    }
    if teacher is not None:
        onward = Counter(rows[w * trials + t].outcome for w, on in taught for t in on.tolist())
        out["held_back_teacher_forward"] = {o: int(onward[o]) for o in sorted(counts)}
    return out


def main() -> int:
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH
    from sim_harness.cmd_eval import add_flights_flags, load_flights

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_flights_flags(ap, shield_default="on", trials_default=10)  # the eval's, its filter forced on
    ap.add_argument("--teacher-recipe", default=None, metavar="RECIPE",
                    help="also label the held-back states with this training recipe's privileged teacher")
    ap.add_argument("--json", default=None, metavar="OUT")
    args = ap.parse_args()
    if args.shield == "off":
        print("stall_census: it counts flights with the filter (--shield on or model)", file=sys.stderr)
        return 2
    args.model = args.model or str(DEFAULT_MODEL_PATH)
    loaded = load_flights("stall_census", args.model, args)
    if loaded is None:
        return 2
    policy, flights = loaded
    teacher = None
    if args.teacher_recipe is not None:
        from quadnav_onboard.config import ConfigError
        from sim_harness.cmd_train import load_recipe
        from sim_harness.rl.config import load_train_config
        from sim_harness.rl.train import privileged_teacher

        try:
            cfg = load_train_config(load_recipe(args.teacher_recipe), args.teacher_recipe)
        except (ConfigError, OSError) as e:
            print(f"stall_census: {e}", file=sys.stderr)
            return 2
        if cfg.imitation_teacher != "privileged" or args.flight_config:
            print(f"stall_census: --teacher-recipe {args.teacher_recipe}: only the privileged teacher of the "
                  f"paper worlds' flights (imitation_teacher {cfg.imitation_teacher!r}, "
                  f"--flight-config {args.flight_config!r})", file=sys.stderr)
            return 2
        teacher = privileged_teacher(cfg, flights.env_config.primitives.scale_m)
    out = census(policy, flights.worlds, args.trials, args.seed, flights.env_config, flights.limits,
                 flights.depth_noise, teacher)
    out["model"] = args.model
    print(f"{out['flights']} flights: {out['outcomes']}")
    print(f"{'outcome':>10} {'decisions':>9} " + " ".join(f"{k:>15}" for k in CLASSES))
    for o, c in out["decisions"].items():
        n = sum(c.values())
        print(f"{o:>10} {n:9d} " + " ".join(f"{c[k]:7d} ({c[k] / max(n, 1):5.1%})" for k in CLASSES))
    print("boxed in, though the true geometry would allow a forward primitive:", out["boxed_in_by_the_view"])
    print("flights short of the goal without a crash, by world:", out["failures_by_world"])
    if teacher is not None:
        print("held back where the teacher flies forward:", out["held_back_teacher_forward"])
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
