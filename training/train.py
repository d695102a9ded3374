"""Train the PointNet++-lite marking classifier on clusters from `roadmark export-clusters`.

    python training/train.py --data out/clusters-a out/clusters-b --out out/train [--epochs 24] [--seed 0]

Reads (from every ``--data`` directory, concatenated) ``points.npy`` (float32 [M, 256, 4], features of ``src/pipeline/learned/features.rs``)
and ``labels.npy`` (uint8 [M], index into ``model.CLASSES``) from ``--data``; holds out the
clusters of every 10th survey (by ``surveys.npy``) for validation, unless ``--val`` names
another export directory. Writes ``model.pt`` (best validation macro-F1),
``calibration.json`` (the unknown threshold) and ``log.json`` into ``--out``.

Training-time augmentation (all isometries or scalings of the prepared point sets, so the
farthest-point order the Rust side produced stays valid):
* rotation by 180 deg with p = 0.5 (markings for the opposite direction), plus a uniform
  +-8 deg jitter (trajectory direction error, curves);
* mirroring across the driving direction with p = 0.5, swapping left/right arrow classes;
* scale x(0.95..1.05), per-point jitter of 1 cm, height-feature scale x(0.5..1.5) (range
  noise of other scanners), intensity-feature noise;
* with p = ``--thin`` a sparser scan of the same marking: 5-60 % of its points (at least 12),
  re-centred and put in farthest-point order again (``thin``). Markings far from the scanner
  or mostly hidden come with a few dozen points; without this the network sees too few.

Sampling is class-balanced (each class drawn equally often); the loss is cross-entropy with
label smoothing 0.05; AdamW, linear warm-up then cosine learning-rate schedule; CPU,
deterministic for a seed.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np
import torch
from torch import nn

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from metrics import calibrate_threshold, confusion, report  # noqa: E402
from model import CLASSES, MIRROR, MarkingNet, Symmetrized  # noqa: E402

MIRROR_IDX = np.arange(len(CLASSES))
for a, b in MIRROR.items():
    MIRROR_IDX[CLASSES.index(a)] = CLASSES.index(b)


def load_many(paths: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Concatenate several export directories; survey ids stay distinct."""
    xs, ys, ss = [], [], []
    offset = 0
    for p in paths:
        x, y, s = load(p)
        xs.append(x)
        ys.append(y)
        ss.append(s.astype(np.int64) + offset)
        offset = int(ss[-1].max()) + 1 if len(s) else offset
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(ss)


def load(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.load(os.path.join(path, "points.npy"))
    y = np.load(os.path.join(path, "labels.npy")).astype(np.int64)
    s_path = os.path.join(path, "surveys.npy")
    s = np.load(s_path) if os.path.exists(s_path) else np.zeros(len(y), dtype=np.int64)
    with open(os.path.join(path, "index.json")) as f:
        index = json.load(f)
    if index["classes"] != CLASSES:
        raise SystemExit(f"{path}: class list {index['classes']} differs from model.CLASSES")
    return x, y, s


def fps_order(xy: np.ndarray) -> np.ndarray:
    """Farthest-point order of all rows of ``xy`` [m, 2] from the point nearest their centroid
    (``features::farthest_point_order``)."""
    m = len(xy)
    d = np.full(m, np.inf)
    cur = int(np.argmin(((xy - xy.mean(0)) ** 2).sum(1)))
    order = np.empty(m, dtype=np.int64)
    for k in range(m):
        order[k] = cur
        d = np.minimum(d, ((xy - xy[cur]) ** 2).sum(1))
        cur = int(np.argmax(d))
    return order


def thin(cluster: np.ndarray, rng: np.random.Generator, lo: float, hi: float) -> np.ndarray:
    """A sparser scan of the same marking (longer range, fewer scan lines): keep a random
    fraction (log-uniform in [lo, hi], at least 12 points) of the cluster's distinct points,
    then redo what ``features.rs`` does: centre on their centroid, farthest-point order, pad by
    cycling. dz and intensity keep their values (their medians hardly move)."""
    n = len(cluster)
    # Rows past the cluster's own point count repeat the FPS order from the start.
    rep = np.flatnonzero((cluster[1:] == cluster[0]).all(1))
    m = int(rep[0]) + 1 if len(rep) else n
    keep = max(12, int(round(m * math.exp(rng.uniform(math.log(lo), math.log(hi))))))
    if keep >= m:
        return cluster
    sub = cluster[np.sort(rng.choice(m, keep, replace=False))].copy()
    sub[:, :2] -= sub[:, :2].mean(0)
    sub = sub[fps_order(sub[:, :2].astype(np.float64))]
    return sub[np.arange(n) % keep]


def augment(x: np.ndarray, y: np.ndarray, rng: np.random.Generator,
            p_thin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    b = len(x)
    x = x.copy()
    y = y.copy()
    for i in np.flatnonzero(rng.random(b) < p_thin):
        x[i] = thin(x[i], rng, 0.05, 0.6)
    ang = rng.uniform(-8, 8, b) * math.pi / 180 + np.where(rng.random(b) < 0.5, math.pi, 0.0)
    c, s = np.cos(ang), np.sin(ang)
    scale = rng.uniform(0.95, 1.05, b)
    ax, ac = x[:, :, 0].copy(), x[:, :, 1].copy()
    x[:, :, 0] = (c[:, None] * ax - s[:, None] * ac) * scale[:, None]
    x[:, :, 1] = (s[:, None] * ax + c[:, None] * ac) * scale[:, None]
    mirror = rng.random(b) < 0.5
    x[mirror, :, 1] *= -1
    y[mirror] = MIRROR_IDX[y[mirror]]
    x[:, :, :2] += rng.normal(0, 0.01 / 4.0, x[:, :, :2].shape)
    x[:, :, 2] = np.clip(x[:, :, 2] * rng.uniform(0.5, 1.5, (b, 1)), -4, 4)
    x[:, :, 3] = np.clip(x[:, :, 3] + rng.normal(0, 0.05, x[:, :, 3].shape), -1, 1)
    return x.astype(np.float32), y


def predict(net: nn.Module, x: np.ndarray, batch: int = 256) -> np.ndarray:
    """Probabilities of the exported graph (``model.Symmetrized``, export.py's default)."""
    net.eval()
    sym = Symmetrized(net).eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(x), batch):
            out.append(sym(torch.from_numpy(x[i : i + batch])).numpy())
    return np.concatenate(out) if out else np.zeros((0, len(CLASSES)), np.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, nargs="+", help="one or more export directories")
    ap.add_argument("--val", nargs="+", help="separate export directories for validation")
    ap.add_argument("--out", required=True)
    ap.add_argument("--epochs", type=int, default=24)
    ap.add_argument("--steps-per-epoch", type=int, default=300)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--thin", type=float, default=0.35,
                    help="probability of the sparse-scan augmentation (train.thin)")
    ap.add_argument("--warmup", type=int, default=200, help="linear learning-rate warm-up steps")
    args = ap.parse_args()

    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(args.seed)
    x, y, surveys = load_many(args.data)
    if args.val:
        vx, vy, _ = load_many(args.val)
    else:
        val_mask = surveys % 10 == 9
        vx, vy = x[val_mask], y[val_mask]
        x, y = x[~val_mask], y[~val_mask]
    print(f"train {len(x)} clusters, validation {len(vx)}")
    print("train per class:", {c: int((y == i).sum()) for i, c in enumerate(CLASSES)})
    by_class = [np.flatnonzero(y == i) for i in range(len(CLASSES))]
    present = [i for i, idx in enumerate(by_class) if len(idx)]

    net = MarkingNet()
    opt = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=1e-4)
    total = args.epochs * args.steps_per_epoch
    warm = max(args.warmup, 0)

    def lr_factor(k: int) -> float:
        if k < warm:
            return (k + 1) / warm
        t = min(k - warm, total - warm) / max(total - warm, 1)
        return 0.5 * (1 + math.cos(math.pi * t))

    sched = torch.optim.lr_scheduler.LambdaLR(opt, lr_factor)
    loss_fn = nn.CrossEntropyLoss(label_smoothing=0.05)
    os.makedirs(args.out, exist_ok=True)
    best = (-1.0, -1)
    log = []
    t0 = time.time()
    for epoch in range(args.epochs):
        net.train()
        running = 0.0
        for _ in range(args.steps_per_epoch):
            cls = rng.choice(present, args.batch)
            idx = np.array([by_class[c][rng.integers(len(by_class[c]))] for c in cls])
            bx, by = augment(x[idx], y[idx], rng, args.thin)
            logits = net(torch.from_numpy(bx))
            loss = loss_fn(logits, torch.from_numpy(by))
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            running += loss.item()
        probs = predict(net, vx)
        cm = confusion(vy, probs.argmax(1), len(CLASSES))
        rep = report(cm, CLASSES, quiet=True)
        macro = rep["macro_f1"]
        log.append({"epoch": epoch, "loss": running / args.steps_per_epoch, "val_macro_f1": macro,
                    "val_f1": rep["f1"], "seconds": time.time() - t0})
        present_val = [i for i in range(len(CLASSES)) if rep["support"][i]]
        worst = sorted(present_val, key=lambda i: rep["f1"][i])[:3]
        print(f"epoch {epoch:2d} loss {running / args.steps_per_epoch:.4f} val macro-F1 {macro:.4f} "
              f"({time.time() - t0:.0f} s); worst " + ", ".join(f"{CLASSES[i]} {rep['f1'][i]:.3f}" for i in worst),
              flush=True)
        if macro >= best[0]:
            best = (macro, epoch)
            torch.save(net.state_dict(), os.path.join(args.out, "model.pt"))
    net.load_state_dict(torch.load(os.path.join(args.out, "model.pt")))
    probs = predict(net, vx)
    threshold = calibrate_threshold(vy, probs, CLASSES.index("unknown"))
    print(f"best epoch {best[1]} (val macro-F1 {best[0]:.4f}); unknown threshold {threshold:.3f}")
    report(confusion(vy, probs.argmax(1), len(CLASSES)), CLASSES)
    with open(os.path.join(args.out, "calibration.json"), "w") as f:
        json.dump({"unknown_threshold": threshold}, f)
    with open(os.path.join(args.out, "log.json"), "w") as f:
        json.dump({"args": vars(args), "epochs": log, "best_epoch": best[1]}, f, indent=1)


if __name__ == "__main__":
    main()
