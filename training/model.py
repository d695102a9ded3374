"""PointNet++-lite marking classifier (PyTorch).

Input: ``points`` float32 [B, N, 4] -- one marking cluster per row, N points in
farthest-point order (``src/pipeline/learned/features.rs``), features
``along, across, dz, intensity`` in the trajectory-aligned frame (metres / 4).
Output of the exported graph: ``probs`` float32 [B, C] (softmax over ``CLASSES``).

Architecture (Qi et al., PointNet++, 2017, single-scale grouping):

* SA1: centroids = the first 64 input points (an FPS prefix, so no sampling loop in the
  graph); each groups its 16 nearest input points (cdist + topk + gather); shared MLP
  4 -> 32 -> 64 on (relative along/across in 0.4 m units, dz, intensity); max over the group.
* SA2: centroids = the first 16 SA1 centroids; 8 nearest SA1 centroids (offsets in 1.5 m units);
  shared MLP (2 + 64) -> 96 -> 128 with batch norm; max.
* Global: MLP (2 + 128) -> 128 -> 256 on the 16 SA2 centroids; max.
* Head: 256 -> 128 -> C with dropout.

About 0.1 M parameters; ~4 M multiply-adds per cluster.
"""

from __future__ import annotations

import torch
from torch import nn

# Output order of the network: contract class names (see CONTRACT.md). solid_line,
# stop_line and crosswalk are also decided by the geometric rules in the pipeline; the
# network knows them so that pieces the rules leave over still get a sensible class.
CLASSES = [
    "solid_line",
    "dashed_line",
    "guideline",
    "straight_arrow",
    "left_arrow",
    "right_arrow",
    "straight_left_arrow",
    "straight_right_arrow",
    "crosswalk",
    "diamond",
    "stop_line",
    "unknown",
]
# Mirroring a cluster across the driving direction swaps these classes.
MIRROR = {
    "left_arrow": "right_arrow",
    "right_arrow": "left_arrow",
    "straight_left_arrow": "straight_right_arrow",
    "straight_right_arrow": "straight_left_arrow",
}

N_POINTS = 256
S1, K1 = 64, 16
S2, K2 = 16, 8
# Relative neighbour offsets are re-expressed in units of about the neighbourhood size
# (input unit = 4 m; SA1 neighbourhoods span ~0.1-0.5 m, SA2 ones ~0.5-2 m), as PointNet++
# normalises them by the ball radius: a 15 cm line width is then an O(1) input instead of
# 0.04, which is what separates an arrow head from a dash end. Absolute size stays in the
# global level's centroid positions (metric frame, no per-cluster scaling).
REL1 = 4.0 / 0.4
REL2 = 4.0 / 1.5


def mlp2d(channels: list[int], norm: bool = True) -> nn.Sequential:
    """Shared MLP over [B, C, S, K], optionally with batch norm (folded at export)."""
    layers: list[nn.Module] = []
    for cin, cout in zip(channels[:-1], channels[1:]):
        if norm:
            layers += [nn.Conv2d(cin, cout, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU()]
        else:
            layers += [nn.Conv2d(cin, cout, 1), nn.ReLU()]
    return nn.Sequential(*layers)


def group(centroids: torch.Tensor, points: torch.Tensor, feats: torch.Tensor, k: int,
          rel_scale: float) -> torch.Tensor:
    """k nearest ``points`` of each centroid (in the along/across plane).

    centroids [B, S, 2], points [B, M, 2], feats [B, M, C] ->
    [B, S, k, 2 + C]: relative position (times ``rel_scale``), then the neighbour's features.
    """
    d = torch.cdist(centroids, points)  # [B, S, M]
    idx = torch.topk(d, k, dim=-1, largest=False).indices  # [B, S, k]
    b, s, _ = idx.shape
    c = feats.shape[-1]
    flat = idx.reshape(b, s * k)
    nb_xy = torch.gather(points, 1, flat.unsqueeze(-1).expand(b, s * k, 2)).reshape(b, s, k, 2)
    nb_f = torch.gather(feats, 1, flat.unsqueeze(-1).expand(b, s * k, c)).reshape(b, s, k, c)
    return torch.cat([(nb_xy - centroids.unsqueeze(2)) * rel_scale, nb_f], dim=-1)


class MarkingNet(nn.Module):
    def __init__(self, n_classes: int = len(CLASSES), dropout: float = 0.3):
        super().__init__()
        # No batch norm on the largest activations (B x 64 x 16 groups): it costs more
        # than the convolutions there on a CPU, and the inputs are already normalised.
        self.sa1 = mlp2d([4, 32, 64], norm=False)
        self.sa2 = mlp2d([2 + 64, 96, 128])
        self.glob = mlp2d([2 + 128, 128, 256])
        self.head = nn.Sequential(
            nn.Linear(256, 128, bias=False),
            nn.BatchNorm1d(128),
            nn.ReLU(),
            nn.Dropout(dropout),
            nn.Linear(128, n_classes),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits [B, C] for points [B, N, 4]."""
        xy = x[:, :, :2]
        rest = x[:, :, 2:]
        c1 = xy[:, :S1]
        g1 = group(c1, xy, rest, K1, REL1)  # [B, S1, K1, 4]
        f1 = self.sa1(g1.permute(0, 3, 1, 2)).amax(dim=3)  # [B, 64, S1]
        c2 = c1[:, :S2]
        g2 = group(c2, c1, f1.transpose(1, 2), K2, REL2)  # [B, S2, K2, 66]
        f2 = self.sa2(g2.permute(0, 3, 1, 2)).amax(dim=3)  # [B, 128, S2]
        g3 = torch.cat([c2.transpose(1, 2), f2], dim=1).unsqueeze(3)  # [B, 130, S2, 1]
        f3 = self.glob(g3).amax(dim=(2, 3))  # [B, 256]
        return self.head(f3)


class WithSoftmax(nn.Module):
    """The exported graph: probabilities instead of logits."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        return torch.softmax(self.net(points), dim=-1)


def mirror_index() -> list[int]:
    """Class permutation of a mirrored cluster (left and right arrows swap)."""
    return [CLASSES.index(MIRROR.get(c, c)) for c in CLASSES]


class Symmetrized(nn.Module):
    """The exported graph with the road's symmetries built in: the mean of the probabilities
    of the cluster, the cluster turned by 180 deg (a marking for the opposite direction),
    and both mirrored across the driving direction (left/right arrow classes swapped back).

    The feature frame and the farthest-point order are equivariant under these isometries
    (``features.rs``), so the four inputs are valid network inputs; training augments with
    the same transforms, the average makes the answer exactly invariant. Costs four network
    evaluations per cluster.
    """

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net
        self.register_buffer("perm", torch.tensor(mirror_index(), dtype=torch.long), persistent=False)
        self.register_buffer("turn", torch.tensor([-1.0, -1.0, 1.0, 1.0]), persistent=False)
        self.register_buffer("flip", torch.tensor([1.0, -1.0, 1.0, 1.0]), persistent=False)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        b = points.shape[0]
        turned = points * self.turn
        x = torch.cat([points, turned, points * self.flip, turned * self.flip], dim=0)
        p = torch.softmax(self.net(x), dim=-1)
        direct = p[: 2 * b].reshape(2, b, -1).sum(0)
        mirrored = p[2 * b :].reshape(2, b, -1).sum(0).index_select(1, self.perm)
        return (direct + mirrored) * 0.25
