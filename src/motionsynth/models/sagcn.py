"""SA-GCN: structure-aware action generation (Yu et al., ECCV 2020, GlocalNet Table 3's strongest row).

A class-conditional GAN over whole 2-D pose clips. The generator turns per-frame noise and the
class into a latent trajectory, decodes it into a draft pose sequence, and refines the draft with
graph convolutions over the *action graph*: one node per joint and frame, bones within a frame,
and, across frames, links between the same joint whose weights come from self-attention over the
frames, kept only for the ``top_k`` most attended past frames (the sparsification that gives the
method its name). Two discriminators judge the result: one on whole clips, one on single frames.

Sources: the paper's abstract (arXiv 2007.01971: self-attention sparsifies the temporal part of the
action graph, "attend to important past frames") and the authors' code (PingYu-iris/SA-GCN
``model.py``, ``train.py``) for every size and step. We could not read the paper's body here, so
no equation numbers are cited; every structural fact below is the code's unless marked ours.

Generator (``[N]`` labels -> ``[N, T, J, D]``):

* **Latent transitions**: per frame, noise ``z_t`` (``noise_dim``) and a linear map of the one-hot
  class (``label_dim``) go through a linear layer and a GRU (``hidden``); the latent of frame ``t``
  is a random start ``s_0 ~ U(0, 1)`` plus the cumulative sum of the GRU outputs up to ``t``
  (smooth latent transitions, after c-SkeletonGAN; ``latent_walk: true``), concatenated with the
  one-hot class. With ``latent_walk: false`` (ours, the ``default`` size) the latent of frame ``t`` is
  the GRU's output itself (see the departures below).
* **Frame attention and decoding**: causal multi-head self-attention over the frames' latents
  (``heads``; each frame attends to itself and earlier frames; the attended values enter through a
  learnt gate ``gamma`` that starts at 0), then per-frame layers of width ``width`` with residual
  paths, and a temporal convolution (kernel 3) to the draft poses ``[N, T, J*D]``.
* **Sparse action graph**: causal self-attention over the draft poses gives frame-to-frame weights
  ``W [N, T, T]`` (averaged over the heads; the draft is also refined by that attention's gated
  residual). Each frame keeps its ``top_k`` largest weights (the others are 0). With bones ``A``
  (``J x J``, self-loops included), the graph over the ``T * J`` nodes is

      A^[(t, j), (t', j')] = [j = j', t != t'] W[t, t'] + [t = t'] A[j, j'] (W[t, t] + 0.1) + 0.1 [t = t', j = j']

  row-normalised (``D^-1 A^``, ``D`` the row sums) and applied as ``H' = D^-1 A^ H``: every node
  becomes the weighted mean of its bones in its own frame, of the same joint in the past frames its
  frame attends to, and of itself.
* **Graph convolutions**: five layers (``gcn_channels`` 32, 64, 64, 128, 128) of a 1x1 channel
  map, the graph product above, and (``node_mixing``, the reference's) a learnt dense map over all
  ``T * J`` nodes; residual paths after the third and fifth layers (1x1 maps of the draft and of the
  third layer's output) and a final 1x1 map to the coordinates. No non-linearity between them, as
  in the reference.

Discriminators (logits; ``sigmoid`` is folded into the loss):

* **sequence** ``D_V``: per frame two LeakyReLU(0.2) layers (``d_width``), the one-hot class
  concatenated, two more layers down to 128, a temporal convolution (kernel 3) to one value per
  frame and a linear map over the ``clip`` frames to one logit;
* **frame** ``D_F``: ``frame_samples`` frames drawn at random from the clip (with replacement, the
  same frame indices for the whole batch, as the reference), per frame two layers plus a linear
  shortcut, the class concatenated, two more layers, one value per frame, a linear map over the
  drawn frames to one logit.

Training (:meth:`adversarial_step`, one iteration of the reference's loop): both discriminators
take one step on the real clip (target ``real_label`` = 0.9: one-sided label smoothing) and on the
generated clip (target 0), then the generator one step on the sum of both discriminators' losses
with target ``real_label``. Adam, lr 2e-4, betas (0.5, 0.999), batch 20, no gradient clipping,
no gradient penalty and no spectral normalisation (the paper names none).

**Class head** (``class_head``): the authors' code as published with the paper (commit 72f4e78,
July 2020; removed in April 2021) gave ``D_V`` a second output, a linear map from its per-frame
values to the classes, and added its cross-entropy against the clip's class to the
discriminators' loss (on real and on generated clips) and to the generator's (on its clips):
an auxiliary-classifier GAN. That code applied ``CrossEntropyLoss`` to softmax outputs (a softmax
twice); ours takes it on the logits.

Choices that are ours, and departures from the reference code
--------------------------------------------------------------
* **No latent walk at our budget** (``latent_walk: false`` in the ``default`` size; ``paper`` keeps the
  reference's walk). The walk adds up the GRU's outputs (each in (-1, 1)) over the clip, from a start in
  ``U(0, 1)``, so a frame's latent can drift up to 50 times a step's size. At our sizes and budget the generator never left the mean pose with
  it: validation MMD_avg 0.89-1.04 over 4,000 steps (the mean pose scores 1.0); 0.94-1.00 over 1,200
  steps with the class head, 0.92-1.01 with the dense node map as well, 0.85-1.01 with a generator
  learning rate of 5e-5 (the discriminators' 2e-4), 1.00-1.07 with the steps scaled by ``1/T``, 0.72-0.82
  with the graph layers bypassed. The discriminators themselves work: against a frozen generator they
  separate real from generated clips within 100 steps. Without the walk, everything else equal, MMD_avg fell to
  0.58-0.70 from step 600 on (in ``make run`` at 1,500 steps: 0.59-0.81 from step 900; its selected step
  at today's 3,000 is in the report's Training section). The price:
  only the GRU's state ties one frame's latent to the next, and the generated motion jitters (11 times
  real test data's frame-to-frame acceleration, the report's jitter column).
* **A generator average** (``average_decay``; 0.999 in the ``default`` size, 0 in ``paper``, the reference's):
  validation and generation sample from an exponential moving average of the generator's weights
  (:class:`~.adversarial.AdversarialModel`), while the trained generator plays the game. Without it the
  criterion swung from round to round by up to 0.4 (on Zen 5, seed 0: ``mmd_motion`` 1.11-1.60 over the
  rounds after the best, chosen at step 1,350 with 1.113), and which round selection kept was a matter of
  luck on each CPU: on an Intel Xeon the same code and seed stayed near the mean pose's level. With it the
  same training selected step 900 at 0.909, the rounds after it 0.97-1.04 up to step 1,800, and then it too
  drifted off (1.14-1.37 up to step 3,000): the average steadies the curve near its best and lowers it, it does
  not end the drift; nor does it free the selected round from the CPU's kernels (measurements in the report).
* **Node features**: each node ``(t, j)`` carries its joint's ``D`` = 2 coordinates as two input
  channels. The reference reshapes its ``[B, 50, 30]`` draft to ``[2B, 50, 15]`` with ``view``,
  which puts the first and second halves of each frame's 30 numbers (joints 0-7.5 and 7.5-15, x
  and y interleaved) on the 15 nodes of one frame; that reading matches neither the joints nor the
  coordinates, so we do not reproduce it.
* The two discriminators are one player with one Adam optimiser: Adam is per parameter and both
  step every iteration, so this equals the reference's two optimisers.
* Logits with ``binary_cross_entropy_with_logits`` instead of ``Sigmoid`` + ``BCELoss``: the same
  loss, without its saturation at float precision.
* Real clips are cut from our ``h36m`` training windows (60 poses at 16.7 Hz, every phase,
  stride 10) at a random offset (:mod:`.adversarial`), where the reference cuts 50-pose clips at
  random starts from frame 300 of each take; checkpoints are selected on the validation split
  (:mod:`.adversarial`), where the reference keeps the best MMD_seq on training clips.
* **Direction of the graph product**: ``D^-1 A^ H``, each node gathering from the past frames its
  frame attends to (the paper's "dynamically attend to important past frames"). The reference
  computes ``H D^-1 A^`` with ``D`` from the column sums, so a node gathers from the *later* frames
  that attend to it, each scaled by its own column sum; and it pairs the half-clips of sample ``b``
  with the attention graph of sample ``2b mod B`` (``A_norm.repeat(2, 1, 1)`` against
  ``view(bs * 2, ...)``). Neither is reproduced.
* The sparse graph's products are computed in factored form (a ``T x T`` product per joint and a
  ``J x J`` product per frame), not as a dense ``[T*J, T*J]`` matrix per clip; the same numbers
  (``tests/test_model_gan.py`` checks them against the dense construction), 10x fewer operations.

Shapes: labels ``[N]`` -> latents ``[N, T, hidden + C]`` -> draft ``[N, T, J*D]`` -> graph features
``[N, channels, T, J]`` -> poses ``[N, T, J, D]``.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .adversarial import AdversarialModel, Update, _count, bce_logits
from .base import Batch, DataSpec

#: clips per pass through the graph layers when no gradient is recorded (sampling): their ``[N, C, T, J]``
#: activations then stay in cache. Bit for bit the samples of one pass at the test's size; at the default
#: size the kernels block some products by batch, and `make run`'s SA-GCN values moved by at most 1.2e-9 relative
GRAPH_CHUNK = 50


def skeleton_adjacency(parents: tuple[int, ...] | list[int], joints: int) -> Tensor:
    """Bones as a ``J x J`` 0/1 matrix with self-loops: joint and parent, and, where the parent was not
    kept (``-1``: the hip-less 15-joint H3.6M 2-D skeleton's right hip, left hip and spine), those
    joints linked to one another in place of the removed root. On that skeleton this is the
    reference's matrix (SA-GCN ``train.py``)."""
    if parents is None or len(parents) != joints:
        raise ValueError(f"the skeleton (parents of {joints} joints) is needed for the graph; got {parents!r}")
    A = torch.eye(joints)
    roots = [j for j, p in enumerate(parents) if p < 0]
    for j, p in enumerate(parents):
        if p >= 0:
            A[j, p] = A[p, j] = 1.0
    for a in roots:
        for b in roots:
            A[a, b] = 1.0
    return A


class FrameAttention(nn.Module):
    """Causal multi-head self-attention over frames with a gated residual (gate ``gamma`` from 0):
    ``x [N, T, F] -> (x + gamma * out, weights averaged over heads [N, T, T])``."""

    def __init__(self, features: int, heads: int):
        super().__init__()
        self.heads = heads
        self.dh = max(features // heads, 1)
        inner = self.heads * self.dh
        self.q, self.k, self.v = (nn.Linear(features, inner) for _ in range(3))
        for lin in (self.q, self.k, self.v):
            nn.init.normal_(lin.weight, 0.0, math.sqrt(2.0 / (features + self.dh)))
        self.out = nn.Linear(inner, features)
        self.gamma = nn.Parameter(torch.zeros(1))

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        N, T, _ = x.shape
        split = lambda y: y.view(N, T, self.heads, self.dh).transpose(1, 2)     # noqa: E731  [N, H, T, dh]
        q, k, v = split(self.q(x)), split(self.k(x)), split(self.v(x))
        scores = q @ k.transpose(-1, -2) / math.sqrt(self.dh)                    # [N, H, T, T]
        future = torch.triu(torch.ones(T, T, dtype=torch.bool, device=x.device), diagonal=1)
        w = scores.masked_fill(future, float("-inf")).softmax(-1)
        y = (w @ v).transpose(1, 2).reshape(N, T, -1)
        return x + self.gamma * self.out(y), w.mean(1)


def sparse_graph(weights: Tensor, top_k: int) -> Tensor:
    """Each frame's ``top_k`` largest attention weights kept, the rest 0: ``[N, T, T]``."""
    k = min(top_k, weights.shape[-1])
    val, idx = weights.topk(k, dim=-1)
    return torch.zeros_like(weights).scatter(-1, idx, val)


def graph_product(h: Tensor, W: Tensor, A: Tensor) -> Tensor:
    """``D^-1 A^ H`` of the module docstring for node features ``h [N, C, T, J]``, sparse frame weights
    ``W [N, T, T]`` and bones ``A [J, J]`` (symmetric), in factored form (no ``[T*J, T*J]`` matrix)."""
    diag = W.diagonal(dim1=-2, dim2=-1)                                          # [N, T]: W[t, t]
    off = W - torch.diag_embed(diag)                                             # W with its diagonal zeroed
    gate = diag + 0.1                                                            # the bones' weight in frame t
    rows = off.sum(-1)[:, :, None] + A.sum(1)[None, None, :] * gate[:, :, None] + 0.1   # [N, T, J]: D
    temporal = torch.einsum("nts,ncsj->nctj", off, h)                            # same joint, attended frames
    spatial = torch.einsum("nctk,jk->nctj", h, A) * gate[:, None, :, None]       # bones within the frame
    return (temporal + spatial + 0.1 * h) / rows[:, None]


class GraphConv(nn.Module):
    """One graph layer: 1x1 channel map, :func:`graph_product`, optional dense node map."""

    def __init__(self, c_in: int, c_out: int, nodes: int | None):
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, 1)
        self.mix = nn.Linear(nodes, nodes) if nodes else None

    def forward(self, h: Tensor, W: Tensor, A: Tensor) -> Tensor:
        y = graph_product(self.conv(h), W, A)
        if self.mix is not None:
            N, C, T, J = y.shape
            y = self.mix(y.reshape(N, C, T * J)).reshape(N, C, T, J)
        return y


class Generator(nn.Module):
    def __init__(self, joints: int, dims: int, classes: int, A: Tensor, noise_dim: int, label_dim: int,
                 rnn_input: int, hidden: int, heads: int, top_k: int, width: int, gcn_channels: list[int],
                 nodes: int | None, latent_walk: bool = True):
        super().__init__()
        self.latent_walk = latent_walk
        F_ = joints * dims
        self.joints, self.dims, self.classes, self.noise_dim, self.hidden, self.top_k = \
            joints, dims, classes, noise_dim, hidden, top_k
        self.register_buffer("A", A)
        self.label_in = nn.Linear(classes, label_dim)
        self.rnn_in = nn.Linear(label_dim + noise_dim, rnn_input)
        self.rnn = nn.GRU(rnn_input, hidden, batch_first=True)
        lat = hidden + classes
        self.attn_latent = FrameAttention(lat, heads)
        self.skip1 = nn.Linear(lat, width)
        self.block1 = nn.Sequential(nn.Linear(lat, width // 2), nn.ReLU(), nn.Linear(width // 2, width), nn.ReLU())
        self.block2 = nn.Sequential(nn.Linear(width, width), nn.ReLU(), nn.Linear(width, width), nn.ReLU())
        self.to_pose = nn.Conv1d(width, F_, 3, padding=1)
        self.attn_pose = FrameAttention(F_, heads)
        c = gcn_channels
        self.gc = nn.ModuleList([GraphConv(a, b, nodes) for a, b in zip([dims, *c[:-1]], c)])
        self.res1 = nn.Conv2d(dims, c[2], 1)
        self.res2 = nn.Conv2d(c[2], c[4], 1)
        self.out = nn.Conv2d(c[4], dims, 1)

    def forward(self, onehot: Tensor, T: int) -> Tensor:
        N = onehot.shape[0]
        z = torch.randn(N, T, self.noise_dim, device=onehot.device)
        lab = self.label_in(onehot)[:, None].expand(-1, T, -1)
        o, _ = self.rnn(self.rnn_in(torch.cat([lab, z], -1)))                    # [N, T, hidden]
        if self.latent_walk:                                                     # the reference: s_0 + sum of steps
            o = torch.rand(N, 1, self.hidden, device=onehot.device) + o.cumsum(1)
        latent = torch.cat([o, onehot[:, None].expand(-1, T, -1)], -1)
        latent, _ = self.attn_latent(latent)
        x1 = self.skip1(latent) + self.block1(latent)
        x2 = x1 + self.block2(x1)
        draft = self.to_pose(x2.transpose(1, 2)).transpose(1, 2)                 # [N, T, J*D]
        draft, W = self.attn_pose(draft)
        W = sparse_graph(W, self.top_k)
        if torch.is_grad_enabled() or N <= GRAPH_CHUNK:
            return self.refine(draft, W)
        return torch.cat([self.refine(draft[i:i + GRAPH_CHUNK], W[i:i + GRAPH_CHUNK])
                          for i in range(0, N, GRAPH_CHUNK)])

    def refine(self, draft: Tensor, W: Tensor) -> Tensor:
        """The graph layers: draft poses ``[N, T, J*D]`` and sparse frame weights ``[N, T, T]`` -> ``[N, T, J, D]``."""
        N, T, _ = draft.shape
        h0 = draft.reshape(N, T, self.joints, self.dims).permute(0, 3, 1, 2)     # [N, D, T, J]
        h = self.gc[0](h0, W, self.A)
        h = self.gc[1](h, W, self.A)
        h3 = self.gc[2](h, W, self.A) + self.res1(h0)
        h = self.gc[3](h3, W, self.A)
        h = self.gc[4](h, W, self.A) + self.res2(h3)
        return self.out(h).permute(0, 2, 3, 1)                                   # [N, T, J, D]


class SequenceDiscriminator(nn.Module):
    def __init__(self, features: int, classes: int, clip: int, width: int, joint: int, bottleneck: int,
                 class_head: bool = False):
        super().__init__()
        act = nn.LeakyReLU(0.2)
        self.frame = nn.Sequential(nn.Linear(features, width), act, nn.Linear(width, width), act)
        self.joint = nn.Sequential(nn.Linear(width + classes, joint), act, nn.Linear(joint, bottleneck), act)
        self.temporal = nn.Conv1d(bottleneck, 1, 3, padding=1)
        self.over_time = nn.Linear(clip, 1)
        self.classify = nn.Linear(clip, classes) if class_head else None   # the 2020 code's auxiliary head

    def forward(self, x: Tensor, onehot: Tensor) -> tuple[Tensor, Tensor | None]:
        """``(real/fake logit [N], class logits [N, C] or None)``."""
        N, T = x.shape[:2]
        h = torch.cat([self.frame(x.reshape(N, T, -1)), onehot[:, None].expand(-1, T, -1)], -1)
        h = self.temporal(self.joint(h).transpose(1, 2))[:, 0]                   # [N, T]
        return self.over_time(h)[:, 0], (self.classify(h) if self.classify is not None else None)


class FrameDiscriminator(nn.Module):
    def __init__(self, features: int, classes: int, frames: int, width: int, bottleneck: int):
        super().__init__()
        act = nn.LeakyReLU(0.2)
        self.frame = nn.Sequential(nn.Linear(features, width), act, nn.Linear(width, width // 2), act)
        self.shortcut = nn.Linear(features, width // 2)
        self.joint = nn.Sequential(nn.Linear(width // 2 + classes, width), act, nn.Linear(width, bottleneck), act)
        self.score = nn.Linear(bottleneck, 1)
        self.over_frames = nn.Linear(frames, 1)

    def forward(self, x: Tensor, onehot: Tensor) -> Tensor:
        N, K = x.shape[:2]
        x = x.reshape(N, K, -1)
        h = torch.cat([self.frame(x) + self.shortcut(x), onehot[:, None].expand(-1, K, -1)], -1)
        return self.over_frames(self.score(self.joint(h))[..., 0])[:, 0]


class SAGCN(AdversarialModel):
    """SA-GCN (module docstring). Hyperparameters: ``noise_dim``, ``label_dim``, ``hidden`` (GRU),
    ``heads``, ``top_k`` (past frames kept per frame), ``width`` (generator), ``gcn_channels`` (5),
    ``node_mixing`` (the reference's dense node map; ties the generator to ``clip`` frames), ``rnn_input``
    (the GRU's input width), ``d_width`` (the sequence discriminator's per-frame layers), ``f_width``
    (the frame discriminator's first layer and both discriminators' class-joint layer), ``d_bottleneck``
    (their last layer before the score), ``frame_samples`` (frames the frame discriminator sees),
    ``real_label`` (smoothed target), ``class_head`` (the 2020 code's auxiliary classifier),
    ``latent_walk`` (the reference's cumulative-sum latent), plus
    :class:`~.adversarial.AdversarialModel`'s ``seed_poses``, ``clip``, ``val_per_class``."""

    def __init__(self, spec: DataSpec, noise_dim: int = 30, label_dim: int = 20, rnn_input: int = 60, hidden: int = 100,
                 heads: int = 3, top_k: int = 5, width: int = 1024,
                 gcn_channels: list[int] | tuple[int, ...] = (32, 64, 64, 128, 128), node_mixing: bool = True,
                 d_width: int = 1000, f_width: int = 1024, d_bottleneck: int = 128, frame_samples: int = 21,
                 real_label: float = 0.9, class_head: bool = False, latent_walk: bool = True,
                 average_decay: float = 0.0, seed_poses: int = 10, clip: int = 50, val_per_class: int = 100):
        super().__init__(spec, seed_poses=seed_poses, clip=clip, val_per_class=val_per_class)
        for name, v, lo in (("noise_dim", noise_dim, 1), ("label_dim", label_dim, 1), ("rnn_input", rnn_input, 1),
                            ("hidden", hidden, 1), ("heads", heads, 1), ("top_k", top_k, 1), ("width", width, 2),
                            ("d_width", d_width, 1), ("f_width", f_width, 2), ("d_bottleneck", d_bottleneck, 1),
                            ("frame_samples", frame_samples, 1)):
            _count(name, v, lo)
        gcn_channels = list(gcn_channels)
        if len(gcn_channels) != 5 or any(isinstance(c, bool) or not isinstance(c, int) or c < 1 for c in gcn_channels):
            raise ValueError(f"gcn_channels must be 5 positive integers (the five graph layers), got {gcn_channels!r}")
        for name, v in (("node_mixing", node_mixing), ("class_head", class_head), ("latent_walk", latent_walk)):
            if not isinstance(v, bool):
                raise ValueError(f"{name} must be true or false, got {v!r}")
        if not (isinstance(real_label, (int, float)) and 0.5 < real_label <= 1.0):
            raise ValueError(f"real_label must lie in (0.5, 1], got {real_label!r}")
        J, D = spec.joints, spec.dims
        self.real_label, self.frame_samples, self.node_mixing = float(real_label), frame_samples, node_mixing
        A = skeleton_adjacency(spec.parents, J)
        self.generator = Generator(J, D, self.num_classes, A, noise_dim, label_dim, rnn_input, hidden, heads, top_k,
                                   width, gcn_channels, self.clip * J if node_mixing else None,
                                   latent_walk)
        self.discriminators = nn.ModuleDict({
            "sequence": SequenceDiscriminator(J * D, self.num_classes, self.clip, d_width, f_width, d_bottleneck,
                                              class_head),
            "frame": FrameDiscriminator(J * D, self.num_classes, frame_samples, f_width, d_bottleneck)})
        self.keep_average(average_decay)

    def sample(self, labels: Tensor, length: int) -> Tensor:
        if self.node_mixing and length != self.clip:
            raise ValueError(f"SA-GCN with node_mixing generates clips of exactly {self.clip} poses (its dense node "
                             f"map is per frame and joint); asked for {length}")
        return self.sampler()(self.one_hot(labels), length)

    def _frames(self, x: Tensor) -> Tensor:
        """``frame_samples`` frames of every clip, at random indices shared by the batch (the reference's draw)."""
        idx = torch.randint(0, x.shape[1], (self.frame_samples,), device=x.device)
        return x[:, idx]

    def _scores(self, x: Tensor, onehot: Tensor, labels: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Sequence logit, frame logit, and the class head's cross-entropy against ``labels`` (0 without it)."""
        v, cls = self.discriminators["sequence"](x, onehot)
        ce = F.cross_entropy(cls, labels) if cls is not None else v.new_zeros(())
        return v, self.discriminators["frame"](self._frames(x), onehot), ce

    def adversarial_step(self, batch: Batch, update: Update) -> dict[str, float]:
        real = self.real_clips(batch)
        labels = self.labels_of(batch).long()
        onehot = self.one_hot(labels)
        fake = self.sample(labels, self.clip)
        rv, rf, rc = self._scores(real, onehot, labels)
        fv, ff, fc = self._scores(fake.detach(), onehot, labels)
        d_v = bce_logits(rv, self.real_label) + bce_logits(fv, 0.0)
        d_f = bce_logits(rf, self.real_label) + bce_logits(ff, 0.0)
        update("discriminator", d_v + d_f + rc + fc)
        gv, gf, gc = self._scores(fake, onehot, labels)
        g_loss = bce_logits(gv, self.real_label) + bce_logits(gf, self.real_label) + gc
        update("generator", g_loss)
        with torch.no_grad():
            peak = max(float(t.abs().max()) for t in (rv, rf, fv, ff, gv, gf))
            logs = {"d_loss": float(d_v + d_f + rc + fc), "g_loss": float(g_loss), "d_sequence": float(d_v),
                    "d_frame": float(d_f), "d_real": float(torch.sigmoid(rv).mean()),
                    "d_fake": float(torch.sigmoid(fv).mean()), "logit_absmax": peak}
            if self.discriminators["sequence"].classify is not None:
                logs.update(class_real=float(rc), class_fake=float(gc))
            return logs
