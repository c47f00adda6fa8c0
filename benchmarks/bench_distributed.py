"""Per-shard figures of the Dask path (:func:`catgraph.distributed.match_fixed_window`).

A local cluster of one-thread worker processes, one shard each, random float32
descriptors; a query that runs along the route across the shard edge. For each setting
(window ``L``, velocities searched) the same query is matched several times, settings
alternated, and per run the script records the time per frame, the bytes each worker
served (halos to its neighbours, summaries to the client), each worker's resident and
peak memory. The one-velocity run (the forward diagonal) is the reference each other
setting is compared with, measured in the same rounds.

These are the per-block figures a 10⁷-place cluster run needs (``docs/live.md``, "A 10⁷-place
map on a cluster"): per shard, the time and the bytes per query frame do not depend on
how many other shards there are, except for the client's reductions.

    python benchmarks/bench_distributed.py [--shard-places 65536] [--repeats 3] [--adaptive-query 640]

With ``--rules`` it times the adaptive window's rules that read the difference rows
("predictive", "decorrelated", "spanning") against rule "unrivalled", alternated in the
same rounds, and writes that table as a section of ``distributed.md``. With
``--identity`` it compares the cluster with the local run on the real data (one shard),
and with ``--identity ... --identity-rule RULE --sharded`` on the real data padded to two
shards, the shard edge in the route's middle (``--identity-confidence changepoint``: with the
confidence "changepoint", counting the values the shards serve along the chosen lines).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

DIM = 512
RESULTS = Path(__file__).parent / "results"


def _reference(n: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    out = np.empty((n, DIM), dtype=np.float32)
    for start in range(0, n, 100_000):
        rng.standard_normal(dtype=np.float32, out=out[start : start + 100_000])
    return out


def _counters(dask_worker):
    import psutil
    from process_memory import peak_rss_mb  # the worker's own peak, not the benchmark's at its spawn

    return {"rss": psutil.Process().memory_info().rss,
            "peak": peak_rss_mb() * 2**20,
            "out": getattr(dask_worker, "transfer_outgoing_bytes_total", 0)}


def measure(shard_places: int, n_shards: int, settings: list[dict], repeats: int) -> list[dict]:
    """Each setting: ``window`` (an int, or ``"adaptive"`` for the default adaptive window),
    ``velocities``, ``block_rows``, ``n_query``; runs alternated, ``repeats`` rounds (a
    setting with ``"once": True`` runs once, after the rounds)."""
    import distributed

    from catgraph import distributed as dd

    reference = _reference(shard_places * n_shards)
    rng = np.random.default_rng(2)
    queries = []
    for setting in settings:
        start_place = shard_places - setting["n_query"] // 2  # the route crosses the shard edge
        noise = 0.3 * rng.standard_normal((setting["n_query"], DIM), dtype=np.float32)
        queries.append((start_place, reference[start_place : start_place + setting["n_query"]] + noise))

    def run(k, client, ref, frames=None):
        setting, (start_place, query) = settings[k], queries[k]
        query = query if frames is None else query[:frames]
        if setting["window"] == "adaptive":
            return dd.match_adaptive_window(query, ref, velocities=setting["velocities"],
                                            block_rows=setting["block_rows"], rule=setting.get("rule", "unrivalled"))
        return dd.match_fixed_window(query, ref, setting["window"], velocities=setting["velocities"],
                                     block_rows=setting["block_rows"])

    runs: dict[int, list] = {k: [] for k in range(len(settings))}
    with distributed.LocalCluster(n_workers=n_shards, threads_per_worker=1, processes=True,
                                  dashboard_address=None, memory_limit=None) as cluster, \
            distributed.Client(cluster) as client:
        ref = dd.shard_reference(reference, "sad", client, shard_places=shard_places)
        client.gather(ref.shards)
        for k in range(len(settings)):  # warm the kernels
            run(k, client, ref, frames=40)
        # the settings run once come after every round: a worker's peak RSS never falls, so
        # the other settings' peaks are their own (and the shard's preparation)
        order = [k for _ in range(repeats) for k, o in enumerate(settings) if not o.get("once")]
        order += [k for k, o in enumerate(settings) if o.get("once")]
        for k in order:
            setting = settings[k]
            before = client.run(_counters)
            t0 = time.perf_counter()
            res = run(k, client, ref)
            seconds = time.perf_counter() - t0
            after = client.run(_counters)
            n_query = setting["n_query"]
            truth = queries[k][0] + np.arange(n_query)
            settle = 100 if setting["window"] == "adaptive" else setting["window"]
            runs[k].append({
                "ms_per_frame": 1000 * seconds / n_query,
                "bytes_out_per_frame": [(a["out"] - b["out"]) / n_query
                                        for a, b in zip(after.values(), before.values())],
                "rss_mb": [a["rss"] / 2**20 for a in after.values()],
                "peak_mb": [a["peak"] / 2**20 for a in after.values()],
                "correct_after": float(np.mean(np.abs(res.match[settle:] - truth[settle:]) <= 1)),
            })
    out = []
    for k, setting in enumerate(settings):
        r = runs[k]
        if setting.get("rule"):  # the rules: each against the default rule, same rounds
            ref_k = [j for j, o in enumerate(settings) if o.get("rule") == "unrivalled"]
        else:
            ref_k = [j for j, o in enumerate(settings)
                     if o["window"] == setting["window"] and o["velocities"] == (1.0,)]
        base = runs[ref_k[0]] if ref_k else None  # the one-velocity run of this window, same rounds
        out.append({**{key: (list(v) if key == "velocities" else v) for key, v in setting.items()},
                    "shard_places": shard_places, "n_shards": n_shards,
                    "ms_per_frame": float(np.median([x["ms_per_frame"] for x in r])),
                    "ms_per_frame_runs": [x["ms_per_frame"] for x in r],
                    "ratio_to_one_velocity": None if base is None else
                    float(np.median([x["ms_per_frame"] / y["ms_per_frame"] for x, y in zip(r, base)])),
                    "bytes_out_per_frame": [float(np.median(v)) for v in zip(*[x["bytes_out_per_frame"] for x in r])],
                    "rss_mb": [float(np.max(v)) for v in zip(*[x["rss_mb"] for x in r])],
                    "peak_mb": [float(np.max(v)) for v in zip(*[x["peak_mb"] for x in r])],
                    "correct_after": r[-1]["correct_after"], "runs": len(r)})
    return out


def _real_cases() -> list[tuple[str, dict]]:
    """The real traverses of the identity checks (Nordland; UJI month 02 against 01), as
    experiment inputs; those whose data are absent are left out."""
    sys.path.insert(0, str(Path(__file__).parent))
    from datasets import DATA, NORDLAND_FRAMES, WIFI_METRES

    cases = []
    if (DATA / "nordland").is_dir():
        d = DATA / "nordland" / "32x16"
        cases.append(("Nordland", {"query": d / "winter", "reference": d / "summer", "tolerance": NORDLAND_FRAMES}))
    if (DATA / "uji-lib").is_dir():
        db = DATA / "uji-lib" / "db"
        cases.append(("UJI 02", {"query": db / "02" / "tst01", "reference": db / "01" / "trn01",
                                 "tolerance_m": WIFI_METRES}))
    return cases


def identity(conditions: list[str], rule: str | None = None) -> list[dict]:
    """The cluster run against the local run on the real data (experiment layer: the
    registry's ``sequence`` method with its defaults, a fixed window of 50, and with the
    adaptive window; every velocity and the hub correction), per dataset and condition:
    the frames whose match, confidence and window length are identical. With ``rule``,
    only the adaptive window, with that window rule."""
    import warnings

    import distributed

    from catgraph.conditions import Condition
    from catgraph.experiment import Experiment, run, run_on_cluster

    cases = _real_cases()
    out = []
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        for name, inputs in cases:
            variants = ({}, {"window": "adaptive"}) if rule is None else ({"window": "adaptive", "rule": rule},)
            for text, params in [(t, p) for p in variants for t in conditions]:
                exp = Experiment(method="sequence", params=params, condition=Condition.parse(text), **inputs)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    local, local_out, _ = run(exp)
                    remote, remote_out, _ = run_on_cluster(exp, client, block_rows=512)
                same = ((local.match == remote.match) & (local.confidence == remote.confidence)
                        & (local.extra["window_length"] == remote.extra["window_length"]))
                out.append({"dataset": name, "window": params.get("window", 50), "condition": text,
                            "frames": int(same.size),
                            "identical": int(same.sum()), "auc_local": local_out["metrics"].get("auc"),
                            "auc_cluster": remote_out["metrics"].get("auc")})
                print(out[-1], flush=True)
    return out


def identity_sharded(conditions: list[str], rule: str, filler_seed: int = 0,
                     confidence: str | None = None) -> list[dict]:
    """The adaptive window with ``rule`` on the real data across a shard edge: each map
    (after its front-end) is padded in front with filler places so that it holds two
    shards of 4096 places and the edge at place 4096 falls in the middle of the route.
    A filler place is a map descriptor picked at random with its values permuted at
    random (seeded: the same values, no place of the route). The cluster
    (:func:`catgraph.distributed.match_adaptive_window` on a ``LocalCluster`` of two
    workers, every default, the hub correction from the padded map, frames without
    information flagged) against :func:`catgraph.sequence.match_sequences` on the whole
    normalised matrix with the same offsets: per dataset and condition, the frames whose
    match, score, velocity, window length and confidence are identical. With ``confidence``,
    both run with that confidence (else the default), and the values the confidence
    "changepoint" has the shards serve along the chosen lines are counted (pairs per frame,
    rounds)."""
    import types
    import warnings

    import distributed

    from catgraph import distributed as dd
    from catgraph.conditions import Condition
    from catgraph.differences import difference_matrix
    from catgraph.experiment import Experiment, _inputs
    from catgraph.hubs import map_hub_offsets
    from catgraph.io import describe_query
    from catgraph.sequence import match_sequences

    cases = _real_cases()
    fields = ("match", "score", "velocity", "window_length", "confidence")
    out = []
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        for name, inputs in cases:
            exp = Experiment(method="sequence", params={"window": "adaptive", "rule": rule}, **inputs)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                the_map, _, _, _, query, _ = _inputs(exp)
            ref = np.asarray(the_map.descriptors)
            n = ref.shape[0]
            filler_places = dd.SHARD_UNIT - n // 2  # the edge at SHARD_UNIT: the route's middle
            rng = np.random.default_rng(filler_seed)
            picks = rng.integers(0, n, size=filler_places)
            filler = np.stack([ref[j][rng.permutation(ref.shape[1])] for j in picks])
            padded = np.ascontiguousarray(np.concatenate([filler, ref]))
            padded_map = types.SimpleNamespace(descriptors=padded, n_places=padded.shape[0], metric=the_map.metric,
                                               frontend=the_map.frontend)
            offsets = map_hub_offsets(padded_map)
            sharded = dd.shard_reference(padded, the_map.metric, client, shard_places=dd.SHARD_UNIT)
            for text in conditions:
                condition = Condition.parse(text)
                q_trav = query if condition.kind == "in-order" else condition.apply(query)
                q, informative = describe_query(the_map, q_trav)
                local = difference_matrix(q, padded, the_map.metric, normalise=True)
                local[~informative] = 0.0
                extra = {} if confidence is None else {"confidence": confidence}
                t0 = time.perf_counter()
                expected = match_sequences(local, rule=rule, hub_offsets=offsets, **extra)
                t_local = time.perf_counter() - t0
                served = {"pairs": 0, "rounds": 0}
                original = dd._Lines.serve

                def counted(self, rel, places, _original=original):
                    served["pairs"] += int(rel.shape[0])
                    served["rounds"] += 1
                    return _original(self, rel, places)

                dd._Lines.serve = counted
                try:
                    t0 = time.perf_counter()
                    got = dd.match_adaptive_window(q, sharded, rule=rule, no_information=~informative,
                                                   hub_offsets=offsets, block_rows=512, **extra)
                    t_cluster = time.perf_counter() - t0
                finally:
                    dd._Lines.serve = original
                same = np.ones(len(q), dtype=bool)
                for f in fields:
                    same &= getattr(got, f) == getattr(expected, f)
                out.append({"dataset": name, "condition": text, "frames": int(same.size),
                            "identical": int(same.sum()), "places": int(padded.shape[0]),
                            "filler": int(filler_places), "shards": len(sharded.bounds),
                            "in_shard_1": int(np.sum(expected.match >= dd.SHARD_UNIT)),
                            "in_filler": int(np.sum(expected.match < filler_places)),
                            "seconds_local": t_local, "seconds_cluster": t_cluster,
                            "line_pairs": served["pairs"], "line_rounds": served["rounds"],
                            "blocks": -(-len(q) // 512)})
                print(out[-1], flush=True)
    return out


def write_sharded(rows: list[dict], conditions: list[str], rule: str, commit: str,
                  confidence: str | None = None) -> list[str]:
    """The across-a-shard-edge table as a section of ``distributed_identity_RULE.md`` (replacing
    the section if present), the rows in ``distributed_identity_RULE_sharded.json``; with a
    ``confidence``, ``distributed_identity_RULE_CONFIDENCE.md`` and its json, with the values
    served along the chosen lines."""
    if confidence is not None:
        return _write_confidence(rows, conditions, rule, commit, confidence)
    lines = [SHARDED_HEADING, "",
             f"`benchmarks/bench_distributed.py --identity {' '.join(conditions)} --identity-rule "
             f"{rule} --sharded` at commit {commit}: each map (after its front-end) padded in front "
             "with filler places (a map descriptor picked at random, its values permuted at random; seed 0) "
             "so that it holds two shards of 4096 places and the shard edge falls in the middle of the route; "
             "`catgraph.distributed.match_adaptive_window` (every default, rule "
             f"\"{rule}\", the hub offsets of the padded map, frames without information flagged) "
             "on a `LocalCluster` of two workers against `catgraph.sequence.match_sequences` on the whole "
             "normalised matrix with the same offsets. The horizon is computed from rows put together from "
             "both workers' columns. Frames whose match, score, velocity, window length and confidence are "
             "identical (bit for bit). Seconds: one run each on this shared 2-core machine, the local matcher on "
             "the precomputed matrix, the cluster (two threads of one process) computing the differences too: "
             "not a speed comparison.", "",
             "| dataset | condition | places (filler) | identical frames | matches in shard 1 | "
             "matches in the filler | seconds local / cluster |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['dataset']} | {r['condition']} | {r['places']} ({r['filler']}) | {r['identical']} / "
              f"{r['frames']} | {r['in_shard_1']} | {r['in_filler']} | {r['seconds_local']:.1f} / "
              f"{r['seconds_cluster']:.1f} |" for r in rows]
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"distributed_identity_{rule}.md"
    text = path.read_text() if path.exists() else ""
    if SHARDED_HEADING in text:
        text = text[:text.index(SHARDED_HEADING)].rstrip("\n") + "\n"
    path.write_text((text + "\n" if text else "") + "\n".join(lines) + "\n")
    (RESULTS / f"distributed_identity_{rule}_sharded.json").write_text(
        json.dumps({"commit": commit, "results": rows}, indent=1))
    return lines


def _write_confidence(rows: list[dict], conditions: list[str], rule: str, commit: str, confidence: str) -> list[str]:
    lines = [f"# Dask path against the local run on the real data (rule \"{rule}\", confidence \"{confidence}\")", "",
             f"`benchmarks/bench_distributed.py --identity {' '.join(conditions)} --identity-rule {rule} "
             f"--identity-confidence {confidence} --sharded` at commit {commit}: as the section \"Across a shard "
             "edge\" of `distributed_identity_spanning.md` (each map padded in front with filler places so that the "
             "shard edge at 4096 falls in the route's middle; a `LocalCluster` of two workers; every default but "
             f"the confidence \"{confidence}\"; blocks of 512 frames). Frames whose match, score, velocity, window "
             "length and confidence are identical (bit for bit); the (frame, place) values the shards served "
             "along the chosen lines for the confidence (16 bytes each: an int32 row and column out, a float64 "
             "back) and the rounds that served them. Seconds: one run each on this shared 2-core machine: not a "
             "speed comparison.", "",
             "| dataset | condition | places (filler) | identical frames | matches in shard 1 | values served "
             "(per frame) | rounds (blocks) | seconds local / cluster |",
             "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['dataset']} | {r['condition']} | {r['places']} ({r['filler']}) | {r['identical']} / "
              f"{r['frames']} | {r['in_shard_1']} | {r['line_pairs']} ({r['line_pairs'] / r['frames']:.2f}) | "
              f"{r['line_rounds']} ({r['blocks']}) | {r['seconds_local']:.1f} / {r['seconds_cluster']:.1f} |"
              for r in rows]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"distributed_identity_{rule}_{confidence}.md").write_text("\n".join(lines) + "\n")
    (RESULTS / f"distributed_identity_{rule}_{confidence}.json").write_text(
        json.dumps({"commit": commit, "results": rows}, indent=1))
    return lines


def write(results: list[dict], path: Path, commit: str) -> None:
    s = results[0]
    lines = ["# Dask path: per-shard figures", "",
             f"`benchmarks/bench_distributed.py` at commit {commit}: `catgraph.distributed` on a `LocalCluster` of "
             f"{s['n_shards']} one-thread worker processes on this shared 2-core machine, one shard each of "
             f"{s['shard_places']:,} places × {DIM} float32 (float32 layout), a query along the route across the "
             "shard edge. Settings alternated; time: median over the runs, and the median of each run's ratio to "
             "the one-velocity run of the same window and round. Bytes: what each worker served per frame "
             "(halos to its neighbour, summaries to the client; median over runs). Memory: largest resident and "
             "peak RSS over the runs (the worker's own `VmHWM`; a process's peak never falls: the peaks include "
             "preparing the shard and every run before, so the adaptive run comes last).", "",
             "| window | velocities | frames (block) | runs | ms per frame | × one velocity "
             "| bytes served per frame and worker | worker RSS (MB) | worker peak RSS (MB) | matches within ±1 |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        v = "1" if r["velocities"] == [1.0] else f"{len(r['velocities'])} (±0.5, ±1, ±2, ±3)"
        w = (f"adaptive (13 lengths, 5–500, rule \"{r.get('rule', 'unrivalled')}\")" if r["window"] == "adaptive"
             else f"L = {r['window']}")
        ratio = "—" if r["ratio_to_one_velocity"] is None else f"{r['ratio_to_one_velocity']:.2f}"
        settle = 100 if r["window"] == "adaptive" else r["window"]
        lines.append(f"| {w} | {v} | {r['n_query']} ({r['block_rows']}) | {r['runs']} | {r['ms_per_frame']:.1f} | "
                     f"{ratio} | " + " / ".join(f"{b / 1000:.1f} KB" for b in r["bytes_out_per_frame"]) + " | "
                     + " / ".join(f"{m:.0f}" for m in r["rss_mb"]) + " | "
                     + " / ".join(f"{m:.0f}" for m in r["peak_mb"]) + f" | {r['correct_after']:.2f} after "
                     f"frame {settle} |")
    text = path.read_text() if path.exists() else ""
    rest = text[text.index(RULES_HEADING):] if RULES_HEADING in text else ""  # the rules' section stays
    path.write_text("\n".join(lines) + "\n" + ("\n" + rest if rest else ""))


RULES_HEADING = "## Window rules that read the rows"

SHARDED_HEADING = "## Across a shard edge"


def write_rules(results: list[dict], path: Path, commit: str) -> None:
    """The rules' table as a section of ``path`` (replacing the section if present)."""
    s = results[0]
    lines = [RULES_HEADING, "",
             f"`benchmarks/bench_distributed.py --rules` at commit {commit}: the adaptive window (13 lengths, 5–500, "
             f"every velocity, confidence \"posterior\") with each window rule, on a `LocalCluster` of "
             f"{s['n_shards']} one-thread worker processes, one shard each of {s['shard_places']:,} places × {DIM} "
             f"float32, {s['n_query']} query frames in blocks of {s['block_rows']}; rules alternated, {s['runs']} "
             "rounds; time: median over the rounds, and the median of each round's ratio to rule \"unrivalled\" in "
             "that round. Bytes: what each worker served per frame (halos, summaries and lookups to the client, "
             "and for \"decorrelated\" and \"spanning\" the rows each worker sends to the worker of shard 0, which "
             "keeps the horizon).", "",
             "| rule | runs | ms per frame | × unrivalled | bytes served per frame and worker | matches within ±1 |",
             "|---|---|---|---|---|---|"]
    for r in results:
        ratio = "—" if r["ratio_to_one_velocity"] is None else f"{r['ratio_to_one_velocity']:.2f}"
        lines.append(f"| {r['rule']} | {r['runs']} | {r['ms_per_frame']:.1f} | {ratio} | "
                     + " / ".join(f"{b / 1000:.1f} KB" for b in r["bytes_out_per_frame"])
                     + f" | {r['correct_after']:.2f} after frame 100 |")
    text = path.read_text() if path.exists() else ""
    if RULES_HEADING in text:
        text = text[:text.index(RULES_HEADING)].rstrip("\n") + "\n"
    path.write_text((text + "\n" if text else "") + "\n".join(lines) + "\n")


def main() -> None:
    from catgraph.sequence import DEFAULT_VELOCITIES

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shard-places", type=int, default=65536)
    parser.add_argument("--shards", type=int, default=2)
    parser.add_argument("--query", type=int, default=192)
    parser.add_argument("--adaptive-query", type=int, default=640)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="distributed")
    parser.add_argument("--identity", nargs="*", metavar="CONDITION",
                        help="only compare cluster and local runs on the real data under these conditions "
                             "(e.g. in-order reverse speed:2)")
    parser.add_argument("--rules", nargs="*", metavar="RULE",
                        help="only time the adaptive window's rules against \"unrivalled\" (default: "
                             "predictive decorrelated spanning), the section of distributed.md")
    parser.add_argument("--identity-rule", metavar="RULE",
                        help="with --identity: only the adaptive window with this rule "
                             "(writes distributed_identity_RULE.md)")
    parser.add_argument("--identity-confidence", metavar="CONFIDENCE", default=None,
                        help="with --sharded: this confidence (writes distributed_identity_RULE_CONFIDENCE.md, with "
                             "the values served along the chosen lines)")
    parser.add_argument("--sharded", action="store_true",
                        help="with --identity and --identity-rule: the maps padded to two shards, the edge in the "
                             "route's middle (appends a section to distributed_identity_RULE.md)")
    args = parser.parse_args()
    if args.sharded:
        if args.identity is None or args.identity_rule is None:
            parser.error("--sharded needs --identity and --identity-rule")
        conditions = args.identity or ["in-order", "reverse", "speed:2"]
        rows = identity_sharded(conditions, args.identity_rule, confidence=args.identity_confidence)
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).parent).stdout.strip()
        lines = write_sharded(rows, conditions, args.identity_rule, commit, args.identity_confidence)
        print("\n".join(lines))
        return
    if args.rules is not None:
        asked = args.rules or ["predictive", "decorrelated", "spanning"]
        rules = ["unrivalled"] + [r for r in asked if r != "unrivalled"]
        block = max(1, args.adaptive_query // 2)
        settings = [{"window": "adaptive", "velocities": DEFAULT_VELOCITIES, "block_rows": block,
                     "n_query": args.adaptive_query, "rule": rule} for rule in rules]
        results = measure(args.shard_places, args.shards, settings, args.repeats)
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).parent).stdout.strip()
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "distributed_rules.json").write_text(json.dumps({"commit": commit, "results": results}, indent=1))
        write_rules(results, RESULTS / f"{args.out}.md", commit)
        print((RESULTS / f"{args.out}.md").read_text())
        return
    if args.identity is not None:
        rows = identity(args.identity or ["in-order", "reverse", "speed:2"], args.identity_rule)
        title = "" if args.identity_rule is None else f" (adaptive window, rule \"{args.identity_rule}\")"
        what = ("the registry's `sequence` method with its defaults (window 50, every velocity, hub correction) "
                "and with `window = adaptive`" if args.identity_rule is None else
                f"the registry's `sequence` method with `window = adaptive`, `rule = {args.identity_rule}` (every "
                "velocity, hub correction)")
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).parent).stdout.strip()
        lines = [f"# Dask path against the local run on the real data{title}", "",
                 f"`benchmarks/bench_distributed.py --identity` at commit {commit}: {what}, `run` against "
                 "`run_on_cluster` "
                 "(one shard: these maps are smaller than 4096 places). Frames whose match, confidence and window "
                 "length are identical (bit for bit):", "",
                 "| dataset | window | condition | identical frames | AUC local | AUC cluster |",
                 "|---|---|---|---|---|---|"]
        lines += [f"| {r['dataset']} | {r['window']} | {r['condition']} | {r['identical']} / {r['frames']} | "
                  f"{r['auc_local']:.4f} "
                  f"| {r['auc_cluster']:.4f} |" for r in rows]
        RESULTS.mkdir(exist_ok=True)
        name = "distributed_identity" + ("" if args.identity_rule is None else f"_{args.identity_rule}")
        (RESULTS / f"{name}.md").write_text("\n".join(lines) + "\n")
        print("\n".join(lines))
        return
    fixed = {"block_rows": 64, "n_query": args.query}
    settings = [{"window": 50, "velocities": (1.0,), **fixed},
                {"window": 50, "velocities": DEFAULT_VELOCITIES, **fixed},
                {"window": 100, "velocities": (1.0,), **fixed},
                {"window": 100, "velocities": DEFAULT_VELOCITIES, **fixed}]
    if args.adaptive_query:
        settings.append({"window": "adaptive", "velocities": DEFAULT_VELOCITIES, "block_rows": args.adaptive_query // 2,
                         "n_query": args.adaptive_query, "once": True})
    results = measure(args.shard_places, args.shards, settings, args.repeats)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).parent).stdout.strip()
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{args.out}.json").write_text(json.dumps({"commit": commit, "results": results}, indent=1))
    write(results, RESULTS / f"{args.out}.md", commit)
    print((RESULTS / f"{args.out}.md").read_text())


if __name__ == "__main__":
    main()
