"""The long fuzz campaign, outside CI: the fuzz tests of tests/test_fuzz_*.py with many
more cases per entry point (hypothesis profile ``campaign``) and the Rust properties
of crates/preisach-core/tests/fuzz.rs (proptest), then a table of cases tried, how each
ended, crashes and hangs.

    python benches/fuzz_campaign.py                 # 10^5 cases per Python fuzz test
    python benches/fuzz_campaign.py --cases 2000    # shorter
    python benches/fuzz_campaign.py --cases 2000 --rust-cases 20000
    python benches/fuzz_campaign.py --minutes 55 --no-rust   # a time budget, spread evenly
    python benches/fuzz_campaign.py --no-python --rust-minutes 50 --rust-cases 100000

With ``--minutes`` each hypothesis test runs on its own share of the time budget, in
batches with fresh seeds, until its share is spent; the table then counts the examples
hypothesis reports having run (``--hypothesis-show-statistics``) as well as the calls.
With ``--rust-minutes`` the Rust properties run one after another, each on its share of
the budget in batches of at most 10^4 cases (a new seed each), up to ``--rust-cases``.

A crash (the process dies) or a hang (one call over tests/fuzzing.py's HANG_S; the
watchdog ends the process) makes that file's run fail and is counted. Every Python call
either returned or was refused with a ValueError naming its argument (the contract of
tests/fuzzing.py; anything else fails the test and shows here as a failure). Run from
the repository root with the package installed (``maturin develop``).
"""
from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from machine import describe  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FILES = ("tests/test_fuzz_api.py", "tests/test_fuzz_files.py", "tests/test_faults.py")


def run_python(cases: int, workers: int) -> tuple[dict[str, dict[str, int]], list[str], float]:
    """Each fuzz file in its own pytest process; returns tallies per test, failures."""
    tally: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    problems: list[str] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        procs = []
        for f in FILES:
            stats = Path(d) / (Path(f).stem + ".jsonl")
            env = dict(os.environ, HYPOTHESIS_PROFILE="campaign", FUZZ_EXAMPLES=str(cases), FUZZ_STATS=str(stats),
                       OPENBLAS_NUM_THREADS="1")
            cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-x", f]
            if f.endswith("test_faults.py"):
                cmd += ["-k", "inputs_are_never_modified"]
            procs.append((f, stats, subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                                     stderr=subprocess.STDOUT, text=True)))
            if len(procs) >= workers:
                _collect(procs.pop(0), tally, problems)
        for p in procs:
            _collect(p, tally, problems)
    return tally, problems, time.perf_counter() - t0


def _collect(item: tuple[str, Path, subprocess.Popen], tally: dict[str, dict[str, int]], problems: list[str]) -> None:
    f, stats, p = item
    out, _ = p.communicate()
    if p.returncode != 0:
        kind = "crash" if p.returncode < 0 else ("hang" if "Timeout (" in out else "failure")
        problems.append(f"{f}: {kind} (exit {p.returncode})\n{out[-3000:]}")
    if stats.exists():
        for line in stats.read_text().splitlines():
            d = json.loads(line)
            tally[d["test"]][d["how"]] += d["n"]


def run_timed(minutes: float, workers: int) -> tuple[dict[str, dict[str, int]], list[str], float]:
    """Every fuzz test on an equal share of ``minutes``: batches of examples, each batch a
    pytest process with a new seed, until the test's share is spent. Tallies calls and
    examples per test (examples: hypothesis's own count of examples run)."""
    tally: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    problems: list[str] = []
    t0 = time.perf_counter()
    end = t0 + 60.0 * minutes
    nodes = _nodes()
    left = [len(nodes)]
    with tempfile.TemporaryDirectory() as d, concurrent.futures.ThreadPoolExecutor(workers) as pool:
        def one(node: str) -> None:
            share = max(0.0, end - time.perf_counter()) * workers / max(1, left[0])
            left[0] -= 1
            _batches(node, time.perf_counter() + share, Path(d), tally, problems)
        list(pool.map(one, nodes))
    return tally, problems, time.perf_counter() - t0


def _nodes() -> list[str]:
    cmd = [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", *FILES,
           "-k", "not killed and not ctrl_c and not syncs"]
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True).stdout
    return [line for line in out.splitlines() if "::" in line]


def _batches(node: str, until: float, d: Path, tally: dict[str, dict[str, int]], problems: list[str]) -> None:
    """Batches of ``node`` until ``until`` (one run if it is not a hypothesis test)."""
    size, seed = 100, 0
    while True:
        seed += 1
        stats = d / f"{abs(hash((node, seed)))}.jsonl"
        env = dict(os.environ, HYPOTHESIS_PROFILE="campaign", FUZZ_EXAMPLES=str(size), FUZZ_STATS=str(stats),
                   OPENBLAS_NUM_THREADS="1")
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-x", node,
               f"--hypothesis-seed={seed}", "--hypothesis-show-statistics"]
        t = time.perf_counter()
        p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        took = time.perf_counter() - t
        out = p.stdout + p.stderr
        test = node.split("::")[1].split("[")[0]
        found = re.findall(r"(\d+) passing(?: examples?)?, (\d+) failing", out)
        tally[test]["examples"] += sum(int(a) + int(b) for a, b in found)
        tally[test]["batches"] += 1
        if stats.exists():
            for line in stats.read_text().splitlines():
                rec = json.loads(line)
                tally[rec["test"]][rec["how"]] += rec["n"]
        if p.returncode != 0:
            kind = "crash" if p.returncode < 0 else ("hang" if "Timeout (" in out else "failure")
            problems.append(f"{node} (seed {seed}): {kind} (exit {p.returncode})\n{out[-3000:]}")
            return
        left = until - time.perf_counter()
        if not found or "nothing left to do" in out or left < 0.2 * took:
            return
        rate = size / max(took - 3.0, 0.5 * took)  # examples per second, less the start-up
        size = int(min(max(50, rate * min(left, 600.0)), 50_000))


def run_rust(cases: int) -> tuple[str, bool, float]:
    t0 = time.perf_counter()
    env = dict(os.environ, PROPTEST_CASES=str(cases))
    p = subprocess.run(["cargo", "test", "--profile", "fastdev", "-p", "preisach-core", "--test", "fuzz"],
                       cwd=ROOT, env=env, capture_output=True, text=True)
    return p.stdout + p.stderr, p.returncode == 0, time.perf_counter() - t0


def run_rust_timed(minutes: float, most: int, batch: int) -> tuple[dict[str, int], list[str], float]:
    """Each property on an equal share of ``minutes`` (what the fast ones leave goes to the
    others): batches of ``batch`` cases (proptest draws a new seed per run) until the
    share is spent or ``most`` cases ran. Returns the cases per property that passed."""
    t0 = time.perf_counter()
    end = t0 + 60.0 * minutes
    cmd = ["cargo", "test", "--profile", "fastdev", "-p", "preisach-core", "--test", "fuzz", "--"]
    listed = subprocess.run(cmd + ["--list"], cwd=ROOT, capture_output=True, text=True).stdout
    props = [line.split(":")[0] for line in listed.splitlines() if line.endswith(": test")]
    plain = set(re.findall(r"fn (\w+)\(\)", (ROOT / "crates/preisach-core/tests/fuzz.rs").read_text()))
    cases: dict[str, int] = {}
    failures: list[str] = []
    for i, prop in enumerate(props):
        until = time.perf_counter() + max(0.0, end - time.perf_counter()) / (len(props) - i)
        cases[prop] = 0
        while cases[prop] < most:
            n = min(batch, most - cases[prop])
            p = subprocess.run(cmd + ["--exact", prop], cwd=ROOT, env=dict(os.environ, PROPTEST_CASES=str(n)),
                               capture_output=True, text=True)
            if p.returncode != 0:
                failures.append(f"{prop}: FAILED (exit {p.returncode})\n{(p.stdout + p.stderr)[-4000:]}")
                break
            cases[prop] += n
            print(f"  {prop}: {cases[prop]} cases ({time.perf_counter() - t0:.0f} s)", flush=True)
            if prop in plain or time.perf_counter() > until:  # a regression test is one case
                break
    return cases, failures, time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=100_000, help="hypothesis examples per Python fuzz test")
    ap.add_argument("--rust-cases", type=int, default=None, help="proptest cases per Rust property (default: --cases)")
    ap.add_argument("--minutes", type=float, default=None,
                    help="instead of --cases: a wall-time budget for the Python fuzz tests, spread evenly")
    ap.add_argument("--rust-minutes", type=float, default=None,
                    help="a wall-time budget for the Rust properties, run one at a time in batches "
                         "(up to --rust-cases each)")
    ap.add_argument("--workers", type=int, default=2, help="pytest processes at once")
    ap.add_argument("--no-rust", action="store_true", help="skip the Rust properties")
    ap.add_argument("--no-python", action="store_true", help="skip the Python fuzz tests")
    a = ap.parse_args()
    print(describe())
    ok = a.no_python or python_table(a.cases, a.workers, a.minutes)
    if not a.no_rust and a.rust_minutes is not None:
        ok = rust_timed_table(a.rust_minutes, a.rust_cases or a.cases) and ok
    elif not a.no_rust:
        ok = rust_table(a.rust_cases or a.cases) and ok
    return 0 if ok else 1


def python_table(cases: int, workers: int, minutes: float | None = None) -> bool:
    if minutes is None:
        tally, problems, secs = run_python(cases, workers)
        print(f"\nPython: {cases} examples per test (hypothesis profile 'campaign'), {secs:.0f} s\n")
    else:
        tally, problems, secs = run_timed(minutes, workers)
        print(f"\nPython: {minutes:g} minutes spread evenly over the tests, {workers} at once "
              f"(hypothesis profile 'campaign'), {secs:.0f} s\n")
    print("| entry point (test) | examples | calls | returned | refused (ValueError naming the argument) |")
    print("|---|---:|---:|---:|---:|")
    total = 0
    for test in sorted(tally):
        d = tally[test]
        n = d["returned"] + d["refused"]
        total += n
        examples = d["examples"] if minutes is not None else "-"
        print(f"| `{test}` | {examples} | {n} | {d['returned']} | {d['refused']} |")
    crashes = sum("crash" in p.split("\n")[0] for p in problems)
    hangs = sum("hang" in p.split("\n")[0] for p in problems)
    fails = len(problems) - crashes - hangs
    print(f"\nPython calls: {total}; crashes: {crashes}; hangs: {hangs}; other failures: {fails}")
    for p in problems:
        print(p)
    return not problems


def rust_table(n: int) -> bool:
    out, passed, secs = run_rust(n)
    tests = [line.split()[1] for line in out.splitlines() if line.startswith("test ") and line.endswith(" ok")]
    print(f"\nRust (proptest, crates/preisach-core/tests/fuzz.rs): {n} cases per property, "
          f"{'all passed' if passed else 'FAILED'}, {secs:.0f} s\n")
    print("| property | cases | result |")
    print("|---|---:|---|")
    src = (ROOT / "crates/preisach-core/tests/fuzz.rs").read_text()
    plain = set(re.findall(r"fn (\w+)\(\)", src))  # regression tests: one case each
    for t in tests:
        print(f"| `{t}` | {1 if t in plain else n} | ok |")
    if not passed:
        print(out[-4000:])
    return passed


def rust_timed_table(minutes: float, most: int) -> bool:
    cases, failures, secs = run_rust_timed(minutes, most, batch=max(1, min(most, 10_000)))
    src = (ROOT / "crates/preisach-core/tests/fuzz.rs").read_text()
    plain = set(re.findall(r"fn (\w+)\(\)", src))  # regression tests: one case each
    print(f"\nRust (proptest, crates/preisach-core/tests/fuzz.rs): {minutes:g} minutes, up to {most} cases "
          f"per property, {'all passed' if not failures else 'FAILED'}, {secs:.0f} s\n")
    print("| property | cases | result |")
    print("|---|---:|---|")
    for prop, n in cases.items():
        failed = any(f.startswith(prop + ":") for f in failures)
        print(f"| `{prop}` | {1 if prop in plain else n} | {'FAILED' if failed else 'ok'} |")
    for f in failures:
        print(f)
    return not failures


if __name__ == "__main__":
    raise SystemExit(main())
