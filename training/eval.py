"""Held-out evaluation of an exported ONNX model on clusters from `roadmark export-clusters`.

    python training/eval.py --model models/marking_classifier.onnx --data out/clusters-heldout

Runs the model with onnxruntime (the same engine the pipeline uses through `ort`), prints
per-class precision/recall/F1, macro-F1 and the confusion matrix, first for the arg-max
class, then with the model's calibrated unknown threshold (what the pipeline reports).
The same numbers come from `roadmark export-clusters ... --eval models/marking_classifier.onnx`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np
import onnxruntime as ort

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from metrics import confusion, decide, report  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--json", help="also write the scores here")
    ap.add_argument("--errors", action="store_true",
                    help="list the misclassified clusters (clusters.csv rows: survey, marking, damage)")
    args = ap.parse_args()
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    sess = ort.InferenceSession(args.model, so, providers=["CPUExecutionProvider"])
    meta = sess.get_modelmeta().custom_metadata_map
    classes = meta["roadmark.classes"].split(",")
    threshold = float(meta.get("roadmark.unknown_threshold", "0.5"))
    with open(os.path.join(args.data, "index.json")) as f:
        index = json.load(f)
    if index["classes"] != classes:
        raise SystemExit("the export's class order differs from the model's")
    x = np.load(os.path.join(args.data, "points.npy"))
    y = np.load(os.path.join(args.data, "labels.npy")).astype(np.int64)
    t0 = time.time()
    probs = np.concatenate([sess.run(None, {"points": x[i : i + args.batch]})[0]
                            for i in range(0, len(x), args.batch)])
    dt = time.time() - t0
    n_batches = -(-len(x) // args.batch)
    print(f"{len(x)} clusters, {dt * 1000 / max(n_batches, 1):.1f} ms per batch of {args.batch} (1 thread)")
    print("\n== argmax ==")
    r1 = report(confusion(y, probs.argmax(1), len(classes)), classes)
    print(f"\n== with the unknown threshold {threshold:.3f} ==")
    r2 = report(confusion(y, decide(probs, classes.index("unknown"), threshold), len(classes)), classes)
    if args.errors:
        import csv

        with open(os.path.join(args.data, "clusters.csv")) as f:
            rows = list(csv.DictReader(f))
        pred = decide(probs, classes.index("unknown"), threshold)
        print("\nmisclassified (thresholded): truth -> prediction (p), survey, marking, points, damage")
        for i in np.flatnonzero(pred != y):
            r = rows[i]
            print(f"{classes[y[i]]:>20} -> {classes[pred[i]]:<20} ({probs[i].max():.2f}) {r['survey']} "
                  f"{r['marking']} {r['points']} {r['damage']}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"classes": classes, "argmax": r1, "thresholded": r2, "threshold": threshold}, f, indent=1)


if __name__ == "__main__":
    main()
