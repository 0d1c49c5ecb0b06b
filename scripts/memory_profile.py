"""Peak memory of ``aibo learn`` per stage (issue 19: at most 1 KB per frame).

    python scripts/memory_profile.py --simulate 1000000 --save /tmp/big.npz   # the log (14 s, 2026-11-25)
    python scripts/memory_profile.py /tmp/big.npz [--max-iter 3] [--out /tmp/model.json] [--json out.json]

Runs ``aibo learn LOG --out OUT --max-iter N --no-resume`` (every other option at its default: starts,
alias search, standard errors) in this process and prints per stage the resident set size (VmRSS; MB here
is 2**20 bytes) at its start, its end and the highest seen during it (sampled every 5 ms by a thread: a
shorter peak can be missed), then ``ru_maxrss`` (the kernel's own peak, bytes), bytes per frame, and the
forward passes the standard errors ran. Stages are marked by wrapping the learner's functions (the screened
starts' EM iterations run inside ``EMLearner._load_or_start``); nothing else changes. ``--simulate``: the
log of the README's measurement (``experiments.loop.simulate``, noise ``paper-sim``, seed 7, as ``aibo
bench``'s scaling log; 1,000,000 frames, 509,246 sightings). Wall times are those of this machine.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import threading
import time

_T0 = time.perf_counter()


def rss_bytes() -> int:
    """The resident set size now (bytes), from /proc/self/status (Linux)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    return 0


def maxrss_bytes() -> int:
    """ru_maxrss (bytes; Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


class Stages:
    """Per-stage RSS: at entry, at exit, and the highest sampled (bytes), with the stage's wall time (s)."""

    def __init__(self, period_s: float = 0.005):
        self.rows: list[dict] = []
        self.current: dict | None = None
        self.stack: list[dict] = []
        self.period_s = period_s
        self._stop = threading.Event()
        threading.Thread(target=self._sample, daemon=True).start()

    def _sample(self) -> None:
        while not self._stop.is_set():
            r = rss_bytes()
            for row in self.stack:
                row["peak"] = max(row["peak"], r)
            time.sleep(self.period_s)

    def enter(self, name: str) -> None:
        r = rss_bytes()
        row = {"stage": name, "depth": len(self.stack), "start": r, "peak": r, "t0": time.perf_counter()}
        self.rows.append(row)
        self.stack.append(row)

    def leave(self) -> None:
        row = self.stack.pop()
        row["end"] = rss_bytes()
        row["peak"] = max(row["peak"], row["end"])
        row["seconds"] = time.perf_counter() - row.pop("t0")

    def wrap(self, owner, attr: str, name: str) -> None:
        """Mark every call of ``owner.attr`` as the stage ``name``."""
        fn = getattr(owner, attr)

        def wrapped(*args, **kwargs):
            self.enter(name)
            try:
                return fn(*args, **kwargs)
            finally:
                self.leave()

        setattr(owner, attr, wrapped)

    def stop(self) -> None:
        self._stop.set()


def simulate(n: int, path: str) -> None:
    from aibo_core import trajectory
    from experiments.loop import simulate as sim

    t0 = time.perf_counter()
    tr = sim({"noise": "paper-sim", "max_steps": n}, n, 7)
    trajectory.save(tr, path)
    print(f"wrote {path}: {tr.n_frames} frames in {time.perf_counter() - t0:.0f} s")


def profile(log: str, max_iter: int, out: str) -> dict:
    stages = Stages()
    import_rss = rss_bytes()
    stages.enter("imports")
    import aibo.cli
    import learners.em.learner as learner
    import learners.em.uncertainty as uncertainty
    from aibo_core import trajectory

    stages.leave()
    stages.enter("log loaded")
    n_frames = trajectory.load(log).n_frames
    stages.leave()
    stages.wrap(learner, "run", "EM iterations (fit.run)")
    for attr in ("_load_or_start", "_alias_search", "_lag_search", "_check", "_uncertainty"):
        stages.wrap(learner.EMLearner, attr, f"EMLearner.{attr}")
    stages.wrap(uncertainty, "_Differences", "  _Differences (base pass)")
    stages.wrap(uncertainty, "_information", "  _information (derivatives)")
    stages.wrap(uncertainty, "_file_jacobian", "  _file_jacobian")
    passes = [0]
    forward = uncertainty.innovations_compiled

    def counted(*args, **kwargs):
        passes[0] += 1
        return forward(*args, **kwargs)

    uncertainty.innovations_compiled = counted  # forward passes of the standard errors
    stages.enter(f"aibo learn --max-iter {max_iter}")
    code = aibo.cli.main(["learn", log, "--out", out, "--max-iter", str(max_iter), "--no-resume"])
    stages.leave()
    stages.stop()
    peak = maxrss_bytes()
    mb = 2**20
    print(f"\n{'stage':40s} {'start MB':>9s} {'peak MB':>9s} {'end MB':>9s} {'s':>7s}")
    print(f"{'(python started)':40s} {import_rss / mb:9.0f}")
    for row in stages.rows:
        name = "  " * row["depth"] + row["stage"]
        print(f"{name:40s} {row['start'] / mb:9.0f} {row['peak'] / mb:9.0f} {row['end'] / mb:9.0f} {row['seconds']:7.1f}")
    print(f"\nru_maxrss {peak:,d} bytes = {peak / 1e9:.3f} GB (10^9 bytes); {peak / n_frames:,.0f} bytes per frame "
          f"over {n_frames:,d} frames; exit code {code}; {time.perf_counter() - _T0:.0f} s in all; "
          f"{passes[0]} forward passes in the standard errors")
    return {"frames": n_frames, "max_iter": max_iter, "ru_maxrss_bytes": peak, "bytes_per_frame": peak / n_frames,
            "uncertainty_passes": passes[0],
            "stages": stages.rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", nargs="?")
    ap.add_argument("--max-iter", type=int, default=3)
    ap.add_argument("--out", default="/tmp/memory_profile_model.json")
    ap.add_argument("--json")
    ap.add_argument("--simulate", type=int, help="simulate a log of this many frames to --save, and stop")
    ap.add_argument("--save")
    args = ap.parse_args()
    if args.simulate:
        if not args.save:
            sys.exit("--simulate needs --save PATH")
        return simulate(args.simulate, args.save)
    if not args.log:
        sys.exit("give a log (or --simulate N --save PATH)")
    report = profile(args.log, args.max_iter, args.out)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
