"""Confusion matrix, per-class precision/recall/F1 and the unknown-threshold calibration."""

from __future__ import annotations

import numpy as np


def confusion(truth: np.ndarray, pred: np.ndarray, k: int) -> np.ndarray:
    """cm[t, p] = number of clusters of true class t predicted as p."""
    cm = np.zeros((k, k), dtype=np.int64)
    np.add.at(cm, (truth, pred), 1)
    return cm


def scores(cm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    tp = np.diag(cm).astype(float)
    support = cm.sum(1)
    predicted = cm.sum(0)
    p = np.divide(tp, predicted, out=np.zeros_like(tp), where=predicted > 0)
    r = np.divide(tp, support, out=np.zeros_like(tp), where=support > 0)
    f = np.divide(2 * p * r, p + r, out=np.zeros_like(tp), where=(p + r) > 0)
    return p, r, f, support


def report(cm: np.ndarray, classes: list[str], quiet: bool = False) -> dict:
    """Per-class P/R/F1 over the classes present in the truth; macro-F1 is their mean."""
    p, r, f, support = scores(cm)
    present = support > 0
    macro = float(f[present].mean()) if present.any() else 0.0
    if not quiet:
        w = max(len(c) for c in classes)
        print(f"{'class':<{w}}  precision  recall     F1  support")
        for i, c in enumerate(classes):
            if support[i] or cm[:, i].sum():
                print(f"{c:<{w}}  {p[i]:9.4f} {r[i]:7.4f} {f[i]:6.4f} {support[i]:8d}")
        print(f"macro-F1 {macro:.4f} over {int(present.sum())} classes, accuracy "
              f"{np.trace(cm) / max(cm.sum(), 1):.4f}, {int(cm.sum())} clusters")
        print("confusion matrix (rows = truth, columns = prediction):")
        short = [c[:6] for c in classes]
        print(" " * (w + 1) + " ".join(f"{s:>6}" for s in short))
        for i, c in enumerate(classes):
            if support[i]:
                print(f"{c:<{w}} " + " ".join(f"{v:6d}" for v in cm[i]))
    return {"precision": p.tolist(), "recall": r.tolist(), "f1": f.tolist(),
            "support": support.tolist(), "macro_f1": macro}


def decide(probs: np.ndarray, unknown: int, threshold: float) -> np.ndarray:
    pred = probs.argmax(1)
    pred[probs.max(1) < threshold] = unknown
    return pred


def calibrate_threshold(truth: np.ndarray, probs: np.ndarray, unknown: int) -> float:
    """The top-probability threshold below which a prediction becomes `unknown` that gives the
    best validation macro-F1 (grid 0.30..0.90; ties go to the lowest threshold)."""
    k = probs.shape[1]
    best_t, best_f = 0.3, -1.0
    for t in np.arange(0.30, 0.901, 0.025):
        cm = confusion(truth, decide(probs, unknown, t), k)
        f = report(cm, [str(i) for i in range(k)], quiet=True)["macro_f1"]
        if f > best_f + 1e-9:
            best_t, best_f = float(t), f
    return best_t
