"""How many of a game's actions can be told apart from (s, s') at all: an upper bound on
what any inverse model can label.

    python benchmarks/atari_action_effect.py --games Qbert Pong Breakout BeamRider --states 1000

Plays each game with uniformly random actions (frame skip 4, no sticky actions, as the
training env). At every step it saves the emulator state, tries each of the game's
actions from it for one agent step (4 frames), and compares the next screens (grayscale,
full 210 x 160 resolution, the max of the last two frames as the preprocessing takes):
actions whose next screens are equal cannot be told apart from (s, s') by any model, so the
inverse model's labels on such pairs carry no information about the action. Prints, per
game, the share of states where no action changes the next screen, where all do, and the
mean number of distinguishable action classes; writes ``--out`` (JSON) and ``--plot``
(a figure: the share of states by number of distinguishable actions) if given.
``--from results/atari/action_effect.json`` redraws a saved result without playing.
A smoke run: ``--games Pong --states 3``.
"""

from __future__ import annotations

import argparse
import json
import os

from torchrl_hybrid.envs.atari import action_classes, rom_path  # noqa: F401  (rom_path: the tests use it)


def plot(results: list[dict], path: str) -> None:
    """Per game, the share of states in which k of its actions give distinct next screens."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(3.2 * len(results), 3.0), sharey=True, squeeze=False)
    for ax, r in zip(axes[0], results):
        ks = list(range(1, r["actions"] + 1))
        share = [r["classes_histogram"].get(str(k), r["classes_histogram"].get(k, 0)) / r["states"] for k in ks]
        ax.bar(ks, share, color=["tab:red"] + ["tab:blue"] * (len(ks) - 1))
        ax.set_xticks(ks)
        ax.set_title(f"{r['game']}: {r['mean_classes']:.2f} of {r['actions']} on average", fontsize=9)
        ax.set_xlabel("distinguishable actions")
    axes[0][0].set_ylabel("share of states")
    fig.suptitle("Which actions (s, s') can tell apart (red: none changes the next screen)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--games", nargs="+", default=["Qbert", "Pong", "Breakout", "BeamRider"])
    p.add_argument("--states", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="write the results as JSON")
    p.add_argument("--plot", default=None, help="write the figure (PNG)")
    p.add_argument("--from", dest="source", default=None, help="read saved results (JSON) instead of playing")
    args = p.parse_args()
    for flag, path in (("--out", args.out), ("--plot", args.plot)):
        if path and not os.path.isdir(os.path.dirname(os.path.abspath(path))):
            p.error(f"{flag} {path}: its folder does not exist")
    if args.source:
        try:
            with open(args.source) as f:
                results = json.load(f)
        except (OSError, json.JSONDecodeError) as err:
            p.error(f"--from {args.source}: {err}")
        if not isinstance(results, list) or not results:
            p.error(f"--from {args.source}: not a list of results written by --out")
    else:
        if args.states < 1:
            p.error(f"--states must be >= 1, got {args.states}")
        for game in args.games:
            try:
                rom_path(game)
            except ValueError as err:
                p.error(str(err))
        results = [action_classes(g, args.states, args.seed) for g in args.games]
    print(f"{'game':>10} {'actions':>7} {'no action visible':>18} {'all distinct':>13} {'mean classes':>13}")
    for r in results:
        print(
            f"{r['game']:>10} {r['actions']:7d} {r['no_action_visible']:18.1%} {r['all_distinct']:13.1%} "
            f"{r['mean_classes']:13.2f}"
        )
    print(
        f"({results[0]['states']} states per game under random play; classes = distinct next screens among the actions)"
    )
    if args.out:
        with open(args.out, "w") as f:
            json.dump(results, f, indent=2)
    if args.plot:
        plot(results, args.plot)
        print(f"figure: {args.plot}")


if __name__ == "__main__":
    main()
