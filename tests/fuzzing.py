"""How the fuzz targets run: a short, derandomized check in the default suite, or a long random campaign.

``FACEGEOM_FUZZ_EXAMPLES=N``: N random examples per target (one hypothesis run).
``FACEGEOM_FUZZ_MINUTES=M``: random examples until M minutes of CPU time per reader are spent, split evenly over
the reader's targets (its seeds: the three PLY encodings, the four glTF rig seeds, JPEG and PNG photos, the rig npz
as bytes and as arrays), so every reader gets the same time
(CPU time, its own and its finished child processes', not wall time, so a campaign on a busy machine is as long
as on a quiet one). The examples come in
hypothesis runs of a fresh random seed each, sized from the rate so far so the last run ends near the budget.
``FACEGEOM_FUZZ_LOG=FILE``: each campaign appends one JSON line there (target, examples, CPU and wall seconds,
``pass`` or the failure's first line), which is what ``make fuzz`` prints at the end.
Neither variable set: 100 examples per target (fewer where a target says so), derandomized so the default suite is
stable.
"""
from __future__ import annotations

import functools
import json
import os
import time

from hypothesis import HealthCheck, given, settings

EXAMPLES = int(os.environ.get("FACEGEOM_FUZZ_EXAMPLES", "100"))
MINUTES = float(os.environ.get("FACEGEOM_FUZZ_MINUTES", "0"))
RANDOM = "FACEGEOM_FUZZ_EXAMPLES" in os.environ or MINUTES > 0
FIRST_RUN = 100          # examples in a campaign's first run, before the rate is known
LARGEST_RUN = 20_000     # a run's examples at most, so the budget is checked now and then

FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=not RANDOM,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow], database=None)


def campaign(body, fuzz: settings | None = None, share: int = 1, **strategies) -> int:
    """Run ``body`` on examples drawn from ``strategies`` (hypothesis ``given`` keywords) under ``fuzz`` settings
    (default :data:`FUZZ`): one run of its ``max_examples``, or with ``FACEGEOM_FUZZ_MINUTES`` runs until the CPU
    budget is spent, this target's ``1/share`` of its reader's. Returns the examples run; a failing example fails
    the test as hypothesis reports it."""
    fuzz = fuzz or FUZZ
    count = [0]

    @functools.wraps(body)
    def counted(*args, **kwargs):
        count[0] += 1
        return body(*args, **kwargs)

    def run(n: int) -> None:
        settings(fuzz, max_examples=n)(given(**strategies)(counted))()

    if MINUTES <= 0:
        run(fuzz.max_examples)
        return count[0]
    budget = MINUTES * 60.0 / share
    cpu0, wall0 = cpu_seconds(), time.monotonic()
    outcome = "pass"
    try:
        n = FIRST_RUN
        while True:
            run(n)
            spent = cpu_seconds() - cpu0
            if spent >= budget:
                break
            rate = count[0] / max(spent, 1e-3)
            n = int(min(LARGEST_RUN, max(FIRST_RUN, rate * (budget - spent))))
    except BaseException as exc:
        outcome = f"{type(exc).__name__}: {(str(exc).splitlines() or [''])[0][:300]}"
        raise
    finally:
        _log(count[0], cpu_seconds() - cpu0, time.monotonic() - wall0, outcome, budget)
    return count[0]


def cpu_seconds() -> float:
    """CPU seconds of this process and of its children that have ended (a reader that parses in a child process,
    as the C3D reader does, spends its time there)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _log(examples: int, cpu: float, wall: float, outcome: str, budget: float) -> None:
    path = os.environ.get("FACEGEOM_FUZZ_LOG")
    if not path:
        return
    target = os.environ.get("PYTEST_CURRENT_TEST", "?").rsplit(" (", 1)[0]
    line = json.dumps({"target": target, "examples": examples, "budget_s": round(budget, 1), "cpu_s": round(cpu, 1), "wall_s": round(wall, 1),
                       "outcome": outcome, "pid": os.getpid(), "ended": time.strftime("%Y-%m-%dT%H:%M:%S")})
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(line + "\n")


def report(path: str) -> int:
    """Print the campaigns logged in ``path`` as a table (the last entry per target); 1 if any did not pass."""
    rows: dict[str, dict] = {}
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if line.strip():
                entry = json.loads(line)
                rows[entry["target"]] = entry
    print(f"{'target':<86} {'examples':>9} {'CPU min':>8} {'wall min':>8}  outcome")
    for target, r in sorted(rows.items()):
        name = target.split("::", 1)[-1]
        print(f"{name:<86} {r['examples']:>9,} {r['cpu_s'] / 60:>8.1f} {r['wall_s'] / 60:>8.1f}  {r['outcome']}")
    failed = [t for t, r in rows.items() if r["outcome"] != "pass"]
    print(f"{len(rows)} campaigns, {sum(r['examples'] for r in rows.values()):,} examples, "
          f"{sum(r['cpu_s'] for r in rows.values()) / 60:.1f} CPU minutes; {len(failed)} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    import sys

    if len(sys.argv) != 2:
        sys.exit("usage: python -m tests.fuzzing LOG   (print the campaigns a FACEGEOM_FUZZ_LOG file holds)")
    sys.exit(report(sys.argv[1]))
