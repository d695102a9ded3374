"""Export a trained MarkingNet checkpoint to a self-contained ONNX file with roadmark metadata.

    python training/export.py --checkpoint out/train/model.pt \
        --out models/marking_classifier.onnx [--unknown-threshold 0.5]

The file has one input ``points`` [batch, 256, 4] (dynamic batch), one output ``probs``
[batch, classes], opset 18, weights inline (no external data), and the metadata keys
``roadmark.classes``, ``roadmark.points``, ``roadmark.features``,
``roadmark.unknown_threshold`` that ``src/pipeline/learned/mod.rs`` checks on load (and the
informative ``roadmark.symmetrized``). By default the graph averages the network over the
road's symmetries (``model.Symmetrized``).
With onnxruntime importable, the exported graph is checked against torch on random input.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
import onnx
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from model import CLASSES, N_POINTS, MarkingNet, Symmetrized, WithSoftmax  # noqa: E402

FEATURE_VERSION = "2"


def export(net: MarkingNet, out: str, unknown_threshold: float, extra_meta: dict[str, str],
           symmetrize: bool = True) -> None:
    net.eval()
    wrapped = (Symmetrized(net) if symmetrize else WithSoftmax(net)).eval()
    example = torch.zeros(2, N_POINTS, 4)
    batch = torch.export.Dim("batch", min=1, max=4096)
    program = torch.onnx.export(
        wrapped,
        (example,),
        dynamo=True,
        opset_version=18,
        external_data=False,
        input_names=["points"],
        output_names=["probs"],
        dynamic_shapes={"points": {0: batch}},
        optimize=True,
        verify=False,
    )
    model = program.model_proto
    meta = {
        "roadmark.classes": ",".join(CLASSES),
        "roadmark.points": str(N_POINTS),
        "roadmark.features": FEATURE_VERSION,
        "roadmark.unknown_threshold": f"{unknown_threshold:.3f}",
        "roadmark.symmetrized": "1" if symmetrize else "0",
        **extra_meta,
    }
    del model.metadata_props[:]
    for k, v in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, v
    model.producer_name = "roadmark training/export.py"
    onnx.checker.check_model(model)
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    onnx.save_model(model, out)
    print(f"wrote {out} ({os.path.getsize(out) / 1024:.0f} KiB)")

    try:
        import onnxruntime as ort
    except ImportError:
        print("onnxruntime not importable: parity check skipped")
        return
    rng = np.random.default_rng(0)
    x = rng.normal(0, 0.5, size=(5, N_POINTS, 4)).astype(np.float32)
    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    got = sess.run(None, {"points": x})[0]
    with torch.no_grad():
        want = wrapped(torch.from_numpy(x)).numpy()
    err = float(np.abs(got - want).max())
    print(f"onnxruntime vs torch: max abs difference {err:.2e}")
    if err > 1e-4:
        raise SystemExit("exported graph disagrees with torch")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", help="state dict from train.py; omit with --untrained")
    ap.add_argument("--untrained", action="store_true", help="export a seeded random network (plumbing tests)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--unknown-threshold", type=float, default=None,
                    help="default: the value calibrated by train.py (calibration.json beside the checkpoint)")
    ap.add_argument("--no-symmetrize", action="store_true",
                    help="export the bare network (default: the mean over the 180 deg turn and the "
                         "mirror image, model.Symmetrized)")
    args = ap.parse_args()
    torch.manual_seed(0)
    net = MarkingNet()
    extra: dict[str, str] = {}
    threshold = 0.5
    if args.checkpoint:
        net.load_state_dict(torch.load(args.checkpoint, map_location="cpu"))
        cal = os.path.join(os.path.dirname(args.checkpoint), "calibration.json")
        if os.path.exists(cal):
            with open(cal) as f:
                threshold = float(json.load(f)["unknown_threshold"])
    elif not args.untrained:
        ap.error("give --checkpoint or --untrained")
    else:
        extra["roadmark.note"] = "untrained placeholder"
    if args.unknown_threshold is not None:
        threshold = args.unknown_threshold
    export(net, args.out, threshold, extra, symmetrize=not args.no_symmetrize)


if __name__ == "__main__":
    main()
