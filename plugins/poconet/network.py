"""The PocoNet network (§III-C): a RandLA-Net backbone, Global Feature Attention, point-wise
3-class output; trained as a siamese pair.

Plain PyTorch, no compiled extensions: the neighbour, sub-sampling and up-sampling indices are
computed per scan in the data pipeline (:mod:`.data`, SciPy's ``cKDTree``), so the model is
gathers, 1x1 "convolutions" (``nn.Linear`` on the channel axis) and pooling. Tensors are
``(batch, points, channels)``.

RandLA-Net (Hu et al., CVPR 2020), per encoder layer: a *dilated residual block* -- two rounds of
local spatial encoding (each neighbour's relative position ``p_i, p_k, p_i - p_k, |p_i - p_k|``
through an MLP, next to its features) and attentive pooling (softmax scores over the ``k``
neighbours weighting their features), with a shortcut -- then random sub-sampling by 4 (the kept
points max-pool their neighbours). The decoder up-samples by nearest neighbour with skip
connections.

Global Feature Attention (PocoNet): on the bottleneck features ``x``, ``f = W_f x``,
``g = W_g x``, ``h = W_h x`` (1x1), attention ``softmax(f g^T)`` over the points, ``r = A h``,
``o = x ⊕ r``, an MLP to 1024 channels and a max-pool over points: the scan's 1024-d *codeword*.
The codeword is broadcast back (through a small projection) to every bottleneck point, so the
decoder's labels see global context. Siamese training runs two random samplings of one scan
through the same weights and penalizes the distance between their codewords (``L_global``).

Sizes: ``d_out = (8, 32, 64, 128)`` (Open3D-ML's RandLA-Net uses 16/64/128/256, 1.24 M
parameters; this variant is sized for a 2-core CPU).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

__all__ = ["NetConfig", "PocoNet", "siamese_loss", "variance_loss"]


@dataclass(frozen=True)
class NetConfig:
    in_features: int = 4  # x, y, z, intensity
    d_out: tuple[int, ...] = (8, 32, 64, 128)
    k: int = 16
    ratio: int = 4
    codeword: int = 1024
    classes: int = 3
    # "sigmoid": one binary output per class, trained with binary cross-entropy (the paper's eq. 6);
    # "softmax": the 3-class cross-entropy of the first checkpoint (kept loadable).
    output: str = "softmax"
    # Where the codeword reaches the points: "bottleneck" (the first checkpoint: concatenated to
    # the bottleneck points only, raw) or "points" (normalized, at the bottleneck and again at
    # every point before the head; see GlobalFeatureAttention for why).
    context: str = "bottleneck"

    def as_dict(self) -> dict:
        return {
            "in_features": self.in_features,
            "d_out": list(self.d_out),
            "k": self.k,
            "ratio": self.ratio,
            "codeword": self.codeword,
            "classes": self.classes,
            "output": self.output,
            "context": self.context,
        }

    @classmethod
    def from_dict(cls, d: dict) -> NetConfig:
        """The config a checkpoint stores (older checkpoints lack the newer keys: their defaults)."""
        return cls(**{**d, "d_out": tuple(d["d_out"])})


def _mlp(c_in: int, c_out: int, act: bool = True, norm: bool = True) -> nn.Sequential:
    """A shared 1x1 layer. Per-neighbour MLPs (``k`` x points rows) skip the normalization: at
    the first layer of a 120k-point scan they run on 1.9 M rows, where a LayerNorm costs more
    than the layer itself."""
    layers: list[nn.Module] = [nn.Linear(c_in, c_out)]
    if norm:
        layers.append(nn.LayerNorm(c_out))
    if act:
        layers.append(nn.LeakyReLU(0.2))
    return nn.Sequential(*layers)


def gather(feats: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``feats (B, N, C)``, ``idx (B, M, K)`` -> ``(B, M, K, C)`` (advanced indexing: no
    expanded index tensor, ~2x faster than ``torch.gather`` here)."""
    b = torch.arange(feats.shape[0], device=feats.device).view(-1, 1, 1)
    return feats[b, idx]


class LocalSpatialEncoding(nn.Module):
    """RandLA-Net's relative point position encoding, ``MLP(p_i ⊕ p_k ⊕ (p_i - p_k) ⊕ |p_i - p_k|)``.

    The first layer is linear in its 10 inputs, so it is split into a per-point term of ``p_i``,
    a per-point term of ``p_k`` (gathered) and one of the distance -- the same function without
    building the ``(N, k, 10)`` input (1.9 M rows at a 120k-point scan's first layer)."""

    def __init__(self, d: int) -> None:
        super().__init__()
        self.mlp = _mlp(10, d, norm=False)

    def forward(self, xyz: torch.Tensor, neigh: torch.Tensor, feats: torch.Tensor) -> torch.Tensor:
        lin = self.mlp[0]
        w = lin.weight  # (d, 10): columns p_i (0:3), p_k (3:6), p_i - p_k (6:9), |p_i - p_k| (9)
        w_centre = w[:, 0:3] + w[:, 6:9]
        w_nb = w[:, 3:6] - w[:, 6:9]
        nb_xyz = gather(xyz, neigh)  # (B, N, K, 3)
        dist = torch.linalg.vector_norm(xyz.unsqueeze(2) - nb_xyz, dim=-1, keepdim=True)
        centre_term = (xyz @ w_centre.T + lin.bias).unsqueeze(2)  # (B, N, 1, d)
        nb_term = gather(xyz @ w_nb.T, neigh)  # (B, N, K, d)
        enc = self.mlp[1:](centre_term + nb_term + dist * w[:, 9])
        return torch.cat([enc, gather(feats, neigh)], dim=-1)  # (B, N, K, d + C)


class AttentivePooling(nn.Module):
    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.score = nn.Linear(c_in, c_in, bias=False)
        self.mlp = _mlp(c_in, c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, N, K, C) -> (B, N, c_out)
        w = torch.softmax(self.score(x), dim=2)
        return self.mlp((w * x).sum(dim=2))


class DilatedResidualBlock(nn.Module):
    def __init__(self, c_in: int, d_out: int) -> None:
        super().__init__()
        self.mlp1 = _mlp(c_in, d_out // 2)
        self.lse1 = LocalSpatialEncoding(d_out // 2)
        self.pool1 = AttentivePooling(d_out, d_out // 2)
        self.lse2 = LocalSpatialEncoding(d_out // 2)
        self.pool2 = AttentivePooling(d_out, d_out)
        self.mlp2 = _mlp(d_out, 2 * d_out, act=False)
        self.shortcut = _mlp(c_in, 2 * d_out, act=False)
        self.act = nn.LeakyReLU(0.2)

    def forward(self, xyz: torch.Tensor, neigh: torch.Tensor, feats: torch.Tensor) -> torch.Tensor:
        x = self.mlp1(feats)
        x = self.pool1(self.lse1(xyz, neigh, x))
        x = self.pool2(self.lse2(xyz, neigh, x))
        return self.act(self.mlp2(x) + self.shortcut(feats))


class GlobalFeatureAttention(nn.Module):
    """Self-attention over the bottleneck points, ``x ⊕ r``, an MLP and a max-pool: the codeword.

    ``normalize`` (checkpoints with ``context="points"``) ends the codeword with a LayerNorm
    without gain or bias, so that it has zero mean and unit variance over its channels. Measured
    reason: with the raw codeword the paper's siamese L2 loss has a free direction -- shrink the
    codeword, grow the next layer -- and the first checkpoint took it: its final global loss was
    4.6e-7 and swapping another scan's codeword into it changed 0.0 % of the predicted classes
    (zeroing it 0.12 %). A normalized codeword cannot shrink; the L2 loss can only make the two
    samplings' codewords agree, which is what it is for."""

    def __init__(self, c: int, codeword: int, normalize: bool = False) -> None:
        super().__init__()
        self.f = nn.Linear(c, max(1, c // 8), bias=False)
        self.g = nn.Linear(c, max(1, c // 8), bias=False)
        self.h = nn.Linear(c, c, bias=False)
        self.mlp = nn.Sequential(_mlp(2 * c, 64), nn.Linear(64, codeword))
        self.norm = nn.LayerNorm(codeword, elementwise_affine=False) if normalize else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, N, C) -> (B, codeword)
        attention = torch.softmax(self.f(x) @ self.g(x).transpose(1, 2), dim=-1)  # (B, N, N)
        r = attention @ self.h(x)
        return self.norm(self.mlp(torch.cat([x, r], dim=-1)).max(dim=1).values)


class PocoNet(nn.Module):
    def __init__(self, config: NetConfig = NetConfig()) -> None:
        super().__init__()
        if config.output not in ("softmax", "sigmoid") or config.context not in ("bottleneck", "points"):
            raise ValueError(f"PocoNet: unknown output {config.output!r} or context {config.context!r}")
        self.config = config
        d0 = 8
        self.inp = _mlp(config.in_features, d0)
        self.encoders = nn.ModuleList()
        c = d0
        skips = []
        for d in config.d_out:
            self.encoders.append(DilatedResidualBlock(c, d))
            skips.append(2 * d)
            c = 2 * d
        self.bottleneck = _mlp(c, c)
        at_points = config.context == "points"
        self.gfa = GlobalFeatureAttention(c, config.codeword, normalize=at_points)
        self.context = _mlp(config.codeword, 32)
        self.decoders = nn.ModuleList()
        c_dec = c + 32
        for skip in reversed([d0, *skips[:-1]]):
            self.decoders.append(_mlp(c_dec + skip, max(skip, 16)))
            c_dec = max(skip, 16)
        # "points": the codeword again beside every point's own features, as PointNet's
        # segmentation head concatenates its global feature to each point.
        self.point_context = _mlp(config.codeword, 16) if at_points else None
        self.head = nn.Sequential(
            _mlp(c_dec + (16 if at_points else 0), 32), nn.Dropout(0.3), nn.Linear(32, config.classes)
        )

    def forward(
        self, batch: dict[str, list[torch.Tensor] | torch.Tensor], codeword: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``batch``: ``xyz`` / ``neigh`` / ``sub`` / ``interp`` lists per layer and ``features``
        (see :func:`lwbench_plugins.poconet.data.prepare`). Returns per-point class logits
        ``(B, N, classes)`` and the codeword ``(B, codeword)``. A given ``codeword`` replaces the
        scan's own in the decoder (the swap / zero ablation of the global module)."""
        xyz, neigh, sub, interp = batch["xyz"], batch["neigh"], batch["sub"], batch["interp"]
        x = self.inp(batch["features"])
        skips = [x]
        for layer, enc in enumerate(self.encoders):
            x = enc(xyz[layer], neigh[layer], x)
            x = gather(x, sub[layer]).max(dim=2).values  # the sampled points pool their neighbours
            skips.append(x)
        x = self.bottleneck(x)
        own = self.gfa(x)
        used = own if codeword is None else codeword.to(own.dtype).expand_as(own)
        ctx = self.context(used).unsqueeze(1).expand(-1, x.shape[1], -1)
        x = torch.cat([x, ctx], dim=-1)
        for j, dec in enumerate(self.decoders):
            layer = len(self.encoders) - 1 - j
            up = gather(x, interp[layer]).squeeze(2)  # nearest point of the coarser layer
            x = dec(torch.cat([up, skips[layer]], dim=-1))
        if self.point_context is not None:
            x = torch.cat([x, self.point_context(used).unsqueeze(1).expand(-1, x.shape[1], -1)], dim=-1)
        return self.head(x), own

    def probabilities(self, logits: torch.Tensor) -> torch.Tensor:
        """Per-class probabilities of logits: softmax, or one sigmoid per class (binary outputs)."""
        return torch.sigmoid(logits) if self.config.output == "sigmoid" else torch.softmax(logits, dim=-1)


def siamese_loss(
    logits: tuple[torch.Tensor, torch.Tensor],
    codewords: tuple[torch.Tensor, torch.Tensor],
    labels: torch.Tensor,
    class_weights: torch.Tensor | None,
    lam: float,
    binary: bool = False,
) -> tuple[torch.Tensor, dict[str, float]]:
    """``L = L_label + lam * L_global`` (eq. 6-7) over both branches of the siamese pair.

    ``binary`` (the paper's eq. 6): one binary cross-entropy per class against its one-hot
    target, each point's classes averaged -- a ranking by the high-priority output needs no
    class weights (the first checkpoint's weighted 3-class cross-entropy, ``binary=False`` with
    RandLA-Net's ``1/(f + 0.02)`` weights, pushed over-prediction of high priority: 0.26-0.29
    precision at its argmax). ``L_global``: the element-wise squared L2 distance between the two
    branches' codewords (mean over channels)."""
    fn = nn.functional
    n_cls = logits[0].shape[-1]
    flat = labels.reshape(-1)
    if binary:
        target = fn.one_hot(flat, n_cls).to(logits[0].dtype)
        w = None if class_weights is None else class_weights.to(logits[0].dtype).expand_as(target)
        l_label = sum(fn.binary_cross_entropy_with_logits(lg.reshape(-1, n_cls), target, weight=w) for lg in logits) / 2
    else:
        l_label = sum(fn.cross_entropy(lg.reshape(-1, n_cls), flat, weight=class_weights) for lg in logits) / 2
    l_global = (codewords[0] - codewords[1]).pow(2).mean()
    total = l_label + lam * l_global
    return total, {"loss": float(total.detach()), "label": float(l_label.detach()), "global": float(l_global.detach())}


def variance_loss(codeword: torch.Tensor, bank: list[torch.Tensor], floor: float = 0.5) -> torch.Tensor:
    """VICReg's variance term (Bardes et al., 2022) over the codeword and the ``bank`` of recent
    scans' codewords (detached): ``mean_c relu(floor - std_c)``, zero while every channel varies
    across scans by at least ``floor`` (the normalized codeword's channels have unit variance
    within a scan, so 1 would ask for codewords as different as noise; VICReg's own is 1 on
    unnormalized embeddings). Not in the paper; measured reason: with the paper's
    loss alone, on a normalized codeword, the codeword became the same for every scan -- the
    siamese L2 loss fell to 7e-6 and swapping another scan's codeword changed 0.0 % of the
    predicted classes (mean change of P(high) 6e-6) after 640 steps -- because a constant
    codeword satisfies the L2 loss exactly. The variance term rules that answer out (the L2
    loss still asks two samplings of one scan for the same codeword) -- and measured, it made the
    codewords differ but not the predictions: the decoder learned to ignore them (swap: 0.0 % of
    classes, mean change of P(high) 1e-4, after 786 steps; docs/poconet.md). Off by default."""
    if not bank:
        return codeword.new_zeros(())
    rows = torch.cat([codeword.reshape(1, -1), *(b.reshape(1, -1) for b in bank)])
    std = torch.sqrt(rows.var(dim=0) + 1e-4)
    return torch.relu(floor - std).mean()
