#!/usr/bin/env python3
"""Check a run's TensorBoard event files against its metrics JSONL.

    python3 scripts/check_tensorboard.py RUN_TB_FOLDER METRICS_JSONL [--tags loss,lr]

Reads the event files with the real `tensorboard` package (so this checks what
`tensorboard --logdir` will show, not our own reading of the format), and the
JSONL (one JSON object a line, an integer "step" and numeric fields). For every
tag (default: each numeric JSONL key other than "step" that the event files
hold) the (step, value) series must equal the JSONL's to float32 precision.

Exit status: 0 OK, 1 a difference (or nothing to compare), 3 no tensorboard package.
"""
import argparse
import json
import math
import sys

REL_TOL = 1e-6  # event files store float32 (TensorBoard's simple_value)


def load_jsonl(path):
    """{key: [(step, value), ...]} for every numeric key, in file order."""
    series = {}
    with open(path) as f:
        for number, line in enumerate(f, 1):
            if not line.strip():
                continue
            row = json.loads(line)
            step = row.get("step")
            if not isinstance(step, int) or isinstance(step, bool):
                sys.exit(f"{path}:{number}: no integer \"step\"")
            for key, value in row.items():
                if key != "step" and value is None:
                    # flat_train writes a non-finite value as null (JSON has no NaN).
                    series.setdefault(key, []).append((step, math.nan))
                elif key != "step" and isinstance(value, (int, float)) and not isinstance(value, bool):
                    series.setdefault(key, []).append((step, float(value)))
    return series


def same_value(got, want):
    if math.isnan(want) or math.isnan(got):
        return math.isnan(want) and math.isnan(got)
    if got == want:
        return True
    if math.isinf(got) and abs(want) > 3.4028234663852886e38:  # overflows float32
        return math.copysign(1, got) == math.copysign(1, want)
    return abs(got - want) <= REL_TOL * abs(want)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tb_folder")
    parser.add_argument("metrics_jsonl")
    parser.add_argument("--tags", help="comma-separated tags (default: the JSONL keys found in the event files)")
    args = parser.parse_args()

    try:
        from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    except ImportError:
        print("check_tensorboard: the `tensorboard` Python package is not installed "
              "(pip install tensorboard)", file=sys.stderr)
        return 3

    accumulator = EventAccumulator(args.tb_folder, size_guidance={"scalars": 0})  # 0: keep every point
    accumulator.Reload()
    tb_tags = set(accumulator.Tags().get("scalars", []))
    expected = load_jsonl(args.metrics_jsonl)

    if args.tags:
        tags = [t.strip() for t in args.tags.split(",") if t.strip()]
    else:
        tags = sorted(k for k in expected if k in tb_tags)
    if not tags:
        print(f"FAIL: no tag to compare (event files: {sorted(tb_tags)}, JSONL keys: {sorted(expected)})")
        return 1

    failures, points = [], 0
    for tag in tags:
        if tag not in tb_tags:
            failures.append(f"{tag}: not in the event files of {args.tb_folder}")
            continue
        if tag not in expected:
            failures.append(f"{tag}: not in {args.metrics_jsonl}")
            continue
        got = [(e.step, e.value) for e in accumulator.Scalars(tag)]
        want = expected[tag]
        problems = []
        if len(got) != len(want):
            problems.append(f"{len(got)} points in TensorBoard, {len(want)} in the JSONL")
        for i, ((gs, gv), (ws, wv)) in enumerate(zip(got, want)):
            if gs != ws or not same_value(gv, wv):
                problems.append(f"point {i}: TensorBoard (step {gs}, {gv!r}) vs JSONL (step {ws}, {wv!r})")
                break  # the first difference is enough to act on
        status = "OK" if not problems else "DIFFERS: " + "; ".join(problems)
        print(f"{tag}: {len(got)} points, steps {got[0][0] if got else '-'}..{got[-1][0] if got else '-'}: {status}")
        if problems:
            failures.append(f"{tag}: " + "; ".join(problems))
        points += len(got)

    if failures:
        print("tensorboard check FAILED:\n  " + "\n  ".join(failures))
        return 1
    print(f"tensorboard check: {len(tags)} tags, {points} points, OK")
    return 0


if __name__ == "__main__":
    sys.exit(main())
