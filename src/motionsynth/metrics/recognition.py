"""Classifier-based generative metrics: FID, recognition accuracy, diversity, multimodality.

These are the action-conditioned generation metrics of Action2Motion (Guo et al.,
ACM MM 2020, Sec. 5 and its ``eval_scripts``), reused with the same definitions by
ACTOR (Petrovich et al., ICCV 2021, ``src/evaluate/tools/...``) and MDM (Tevet et al.,
ICLR 2023, ``eval/a2m``). They all read a motion through an *action classifier* trained
on real data; here the pipeline trains that classifier itself (:func:`train_classifier`)
on the train split of the dataset it evaluates, so no pretrained weights are needed.

The classifier (:class:`ActionClassifier`)
------------------------------------------
The structure and sizes of Action2Motion's ``MotionDiscriminator`` used as its
recognition / FID network:

* input ``x`` float32 ``[B, T, F]``: ``T`` normalised poses flattened to ``F = J*D``
  (a ``[B, T, J, D]`` array is flattened for you);
* a GRU, 2 layers, hidden size 128 (batch-first here; the reference is time-first);
* ``h = output of the last GRU layer at the last frame`` ``[B, 128]``;
* **features** ``f = tanh(W1 h + b1)`` ``[B, 30]``: the vector FID, diversity and
  multimodality are computed on (the reference's ``MotionDiscriminatorForFID``
  returns exactly this tanh output);
* **logits** ``W2 f + b2`` ``[B, C]``; the predicted class is their arg-max.

One deliberate difference: the reference draws the GRU's initial hidden state from
``N(0, 1)`` on every call (``initHidden`` = ``torch.randn``), which makes its features
and predictions random; here it is zero (PyTorch's default), so features and every
metric below are deterministic functions of the input and the seed.

Training (:func:`train_classifier`) is plain cross-entropy with Adam on the TRAIN
split only; the validation split only selects the epoch whose weights are returned
(highest val accuracy, ties to the lower val loss; the last epoch without val data).
Everything is seeded: the weight init (``torch.manual_seed(seed)`` inside a forked
RNG, so the caller's global RNG is untouched) and the batch order of epoch ``e``
(``numpy.random.default_rng([seed, e]).permutation``); with the same ``threads`` two
runs give bit-identical weights.

Precision. ``train_classifier(dtype=...)`` trains and runs the classifier in float32 (the
default here, and the reference's) or float64. Bit-identical weights hold on one machine only:
another CPU makes MKL take other GEMM kernels (an AVX2-only CPU instead of an AVX-512 one),
whose float32 rounding differs by about 1e-7, and a few hundred Adam steps, with the epoch
selection on top, turn that into a visibly different feature space. Emulated on one AVX-512
machine with ``MKL_ENABLE_INSTRUCTIONS=AVX2``, the float32 classifier of the generative suite
chose another epoch on two of four datasets, and the FID of Gaussian noise on
``bandai2_locomotion`` went from 11.3 to 3.8 (25 of the 36 reference values of the four
datasets stayed within 5 %). In float64 all 36 did: the largest change was 3.4 % (the real-data
FID of 0.10 on ``bandai2_locomotion``), none above 0.1 % on the other three datasets. The
features of a small test classifier moved by 9e-16 in float64 against 4.5e-7 in float32
(``tests/test_metrics_recognition.py``). The weights keep their dtype when saved and loaded;
inputs stay float32 and are cast per batch.

The metrics
-----------
Let ``f(x)`` be the 30-d classifier features of a motion ``x``.

* **FID** (Heusel et al. 2017): with ``mu_r, S_r`` and ``mu_g, S_g`` the mean and the
  covariance (``ddof = 1``, as ``np.cov``) of the real and generated features,
  ``FID = ||mu_r - mu_g||^2 + Tr(S_r + S_g - 2 (S_r S_g)^{1/2})``. The trace of the
  matrix square root is computed without scipy through a symmetric PSD route:
  ``R = S_r^{1/2}`` (eigen-decomposition, eigenvalues clamped at 0); ``S_r S_g = R (R S_g)``
  has the eigenvalues of ``(R S_g) R = R S_g R``, which is symmetric PSD, so
  ``Tr((S_r S_g)^{1/2}) = sum_i sqrt(max(lambda_i(R S_g R), 0))``. This needs no inverse,
  so singular covariances (fewer samples than 31, or constant features) are fine.
  All in float64; the result is clamped at 0 (rounding can leave ``-1e-13``).
* **Recognition accuracy**: the fraction of generated motions ``x_i`` of requested
  class ``c_i`` with ``argmax logits(x_i) == c_i``.
* **Diversity** (Action2Motion ``S_d = 200``): draw ``S_d`` index pairs ``(i_k, j_k)``,
  both uniformly **with replacement** from all ``N`` samples (as the reference code's two
  ``np.random.randint(0, N, S_d)`` draws), ``Div = 1/S_d sum_k ||f_{i_k} - f_{j_k}||_2``.
* **Multimodality** (Action2Motion ``S_l = 20``): for every class ``c``, draw ``S_l``
  pairs of samples of class ``c`` the same way, and
  ``MModality = 1/(C S_l) sum_c sum_k ||f_{c,i_k} - f_{c,j_k}||_2``: the mean over classes
  of each class's mean pair distance (every class has the same ``S_l`` pairs, so this
  equals the reference's pooled mean).

Sample counts. The number of pairs is always ``pairs``, whatever the set size: sampling
with replacement needs no more than 2 samples, and a set smaller than ``pairs`` just
reuses samples (Action2Motion/ACTOR/MDM generate ``>= 200`` motions in total and
evaluate on many per class; keep that order for comparable numbers). A pair may draw
the same sample twice (distance 0), as in the reference code; the expected value is then
``(1 - 1/n)`` times the mean distance between distinct samples of a set of ``n``, a
visible bias for small classes. ``distinct=True`` draws ``j_k`` from the other ``n - 1``
samples instead (an unbiased estimate of the mean distinct-pair distance).
A set (diversity) or a class (multimodality) with fewer than 2 samples has no pair:
that is a ``ValueError`` naming the classes, unless ``skip_small=True`` leaves those
classes out of the class average (never silently: :func:`multimodality_per_class`
reports which classes were used). The reference code would loop forever on such a class.

FID compares feature *distributions*, class mix included: draw the generated set with the
class labels of the real reference set (as Action2Motion/ACTOR do), or a class-mix
difference dominates the score. :func:`window_arrays` turns a prepared split
(:class:`motionsynth.training.data.WindowData`) into the ``(x, y)`` arrays used here.

Random draws use a local ``numpy.random.default_rng(seed)``, not the global RNG, so the
reference's exact index draws are not reproduced, only their distribution.
"""

from __future__ import annotations

import copy
import time
from typing import Any, Callable

import numpy as np
import torch
from torch import Tensor, nn

__all__ = [
    "ActionClassifier", "train_classifier", "features", "predict", "accuracy", "recognition_accuracy",
    "confusion_matrix", "fid", "frechet_distance", "feature_stats", "diversity", "multimodality",
    "multimodality_per_class", "generative_metrics", "DTYPES", "save_classifier", "load_classifier", "window_arrays",
]

#: Action2Motion's sample counts: pairs for diversity (S_d) and per class for multimodality (S_l)
DIVERSITY_PAIRS = 200
MULTIMODALITY_PAIRS = 20
#: the precisions the classifier trains and runs in (module docstring: "Precision")
DTYPES = ("float32", "float64")


# --------------------------------------------------------------------------- the classifier

class ActionClassifier(nn.Module):
    """GRU action classifier after Action2Motion's ``MotionDiscriminator``.

    ``input_size`` = ``F = J*D``; ``num_classes`` = ``C``. ``forward(x)`` maps ``[B, T, F]``
    to logits ``[B, C]``; :meth:`features` maps it to the ``[B, feature_size]`` (30) tanh
    features. The GRU starts from a zero hidden state (the reference: random).
    """

    def __init__(self, input_size: int, num_classes: int, hidden_size: int = 128, num_layers: int = 2,
                 feature_size: int = 30):
        super().__init__()
        for name, v in (("input_size", input_size), ("num_classes", num_classes), ("hidden_size", hidden_size),
                        ("num_layers", num_layers), ("feature_size", feature_size)):
            if int(v) != v or v < 1:
                raise ValueError(f"ActionClassifier: {name} must be a positive integer; got {v!r}")
        if num_classes < 2:
            raise ValueError(f"ActionClassifier: num_classes must be >= 2; got {num_classes}")
        self.hparams = dict(input_size=int(input_size), num_classes=int(num_classes), hidden_size=int(hidden_size),
                            num_layers=int(num_layers), feature_size=int(feature_size))
        self.input_size, self.num_classes = int(input_size), int(num_classes)
        self.recurrent = nn.GRU(input_size, hidden_size, num_layers, batch_first=True)
        self.to_features = nn.Linear(hidden_size, feature_size)   # the reference's linear1
        self.head = nn.Linear(feature_size, num_classes)          # the reference's linear2

    def features(self, x: Tensor) -> Tensor:
        """``[B, T, F]`` -> ``[B, feature_size]``: ``tanh(W1 h_T + b1)``."""
        out, _ = self.recurrent(x)                                 # [B, T, H]
        return torch.tanh(self.to_features(out[:, -1]))            # [B, 30]

    def forward(self, x: Tensor) -> Tensor:
        """``[B, T, F]`` -> logits ``[B, C]``."""
        return self.head(self.features(x))


def save_classifier(model: ActionClassifier, path, **meta: Any) -> None:
    """Write ``{"hparams", "state_dict", "meta"}`` to ``path`` (reload with :func:`load_classifier`);
    the weights keep their dtype."""
    torch.save({"hparams": model.hparams, "state_dict": model.state_dict(), "meta": meta}, path)


def load_classifier(path) -> tuple[ActionClassifier, dict]:
    """The classifier saved by :func:`save_classifier`, in eval mode and in the dtype it was saved
    in, and its ``meta`` dict."""
    blob = torch.load(path, map_location="cpu", weights_only=True)
    model = ActionClassifier(**blob["hparams"])
    model.to(next(iter(blob["state_dict"].values())).dtype)
    model.load_state_dict(blob["state_dict"])
    return model.eval(), blob.get("meta", {})


def window_arrays(data, idx: Any = None, chunk: int = 2048) -> tuple[np.ndarray, np.ndarray]:
    """Classifier inputs from a :class:`motionsynth.training.data.WindowData` split: the
    normalised windows ``idx`` (default: all) as ``x`` float32 ``[N, T, J*D]`` and their
    sequence labels ``y`` int64 ``[N]`` (gathered ``chunk`` windows at a time)."""
    idx = np.arange(len(data)) if idx is None else np.asarray(idx, dtype=np.int64)
    if len(idx) == 0:
        raise ValueError("window_arrays: no windows selected (empty split?)")
    if data.num_classes < 1:
        raise ValueError("window_arrays: the data has no class labels")
    xs, ys = [], []
    for s in range(0, len(idx), chunk):
        b = data.batch(idx[s:s + chunk])
        xs.append(b.pose.reshape(b.pose.shape[0], b.pose.shape[1], -1).numpy())
        ys.append(b.labels.numpy())
    return np.concatenate(xs), np.concatenate(ys)


# --------------------------------------------------------------------------- input checks

def _as_motion(x: Any, name: str, input_size: int | None = None) -> np.ndarray:
    """``[N, T, F]`` (or ``[N, T, J, D]``, flattened) finite float32 array."""
    a = x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)
    if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
        raise ValueError(f"{name} must be a real numeric array; got dtype {a.dtype}")
    if a.ndim == 4:
        a = a.reshape(a.shape[0], a.shape[1], -1)
    if a.ndim != 3:
        raise ValueError(f"{name} must have shape [N, T, F] (or [N, T, J, D]); got shape {a.shape}")
    if a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"{name} is empty: shape {a.shape}")
    if input_size is not None and a.shape[2] != input_size:
        raise ValueError(f"{name} has {a.shape[2]} features per frame; the classifier takes F = {input_size}")
    a = np.ascontiguousarray(a, dtype=np.float32)
    bad = ~np.isfinite(a)
    if bad.any():
        raise ValueError(f"{name} has {int(bad.sum())} non-finite values (NaN or inf) in "
                         f"{int(bad.any(axis=(1, 2)).sum())} of its {a.shape[0]} samples")
    return a


def _as_labels(y: Any, n: int, num_classes: int | None, name: str, data_name: str) -> np.ndarray:
    """1-D int64 labels, one per sample, each in ``[0, num_classes)``."""
    a = y.detach().cpu().numpy() if isinstance(y, Tensor) else np.asarray(y)
    if a.ndim != 1:
        raise ValueError(f"{name} must be 1-D, one class index per sample; got shape {a.shape}")
    if len(a) != n:
        raise ValueError(f"{name} has {len(a)} entries but {data_name} has {n} samples")
    if a.dtype == bool or not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{name} must hold integer class indices; got dtype {a.dtype}")
    if np.issubdtype(a.dtype, np.floating):
        if not np.isfinite(a).all() or (a != np.round(a)).any():
            raise ValueError(f"{name} holds NaN or non-integer values; class indices must be integers")
    a = a.astype(np.int64)
    hi = num_classes if num_classes is not None else None
    out = (a < 0) | (a >= hi) if hi is not None else a < 0
    if out.any():
        rng = f"[0, {hi})" if hi is not None else ">= 0"
        raise ValueError(f"{name} has {int(out.sum())} labels outside {rng}, e.g. {a[out][:5].tolist()}")
    return a


def _as_feats(f: Any, name: str, min_rows: int = 1) -> np.ndarray:
    """``[N, K]`` finite float64 features."""
    a = f.detach().cpu().numpy() if isinstance(f, Tensor) else np.asarray(f)
    if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
        raise ValueError(f"{name} must be a real numeric array; got dtype {a.dtype}")
    if a.ndim != 2:
        raise ValueError(f"{name} must have shape [N, K] (one feature vector per sample); got shape {a.shape}")
    if a.shape[0] < min_rows or a.shape[1] == 0:
        raise ValueError(f"{name} needs at least {min_rows} samples of >= 1 feature; got shape {a.shape}")
    a = a.astype(np.float64)
    bad = ~np.isfinite(a)
    if bad.any():
        raise ValueError(f"{name} has {int(bad.sum())} non-finite values (NaN or inf)")
    return a


def _check_count(v: Any, name: str, minimum: int = 1) -> int:
    if isinstance(v, bool) or int(v) != v or v < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}; got {v!r}")
    return int(v)


# --------------------------------------------------------------------------- classifier use

def _forward_batched(model: ActionClassifier, x: np.ndarray, fn, batch_size: int) -> np.ndarray:
    model_was_training = model.training
    model.eval()
    p = next(model.parameters())
    outs = []
    with torch.no_grad():
        for s in range(0, len(x), batch_size):
            outs.append(fn(torch.from_numpy(x[s:s + batch_size]).to(p.device, p.dtype)).cpu())
    model.train(model_was_training)
    return torch.cat(outs).numpy()


def features(model: ActionClassifier, x: Any, batch_size: int = 512) -> np.ndarray:
    """Classifier features of motions ``x`` ``[N, T, F]``: float64 ``[N, 30]``."""
    a = _as_motion(x, "x", model.input_size)
    return _forward_batched(model, a, model.features, _check_count(batch_size, "batch_size")).astype(np.float64)


def predict(model: ActionClassifier, x: Any, batch_size: int = 512) -> np.ndarray:
    """Predicted class (arg-max of the logits) of motions ``x`` ``[N, T, F]``: int64 ``[N]``."""
    a = _as_motion(x, "x", model.input_size)
    logits = _forward_batched(model, a, model, _check_count(batch_size, "batch_size"))
    return logits.argmax(1).astype(np.int64)


def accuracy(model: ActionClassifier, x: Any, y: Any, batch_size: int = 512) -> float:
    """Fraction of motions ``x`` ``[N, T, F]`` whose predicted class equals ``y`` ``[N]``."""
    a = _as_motion(x, "x", model.input_size)
    lab = _as_labels(y, len(a), model.num_classes, "y", "x")
    return float((predict(model, a, batch_size) == lab).mean())


def recognition_accuracy(model: ActionClassifier, gen_x: Any, gen_labels: Any, batch_size: int = 512) -> float:
    """Action recognition accuracy of generated motions ``gen_x`` ``[N, T, F]`` conditioned on
    classes ``gen_labels`` ``[N]``: the fraction the classifier assigns to their requested class."""
    a = _as_motion(gen_x, "gen_x", model.input_size)
    lab = _as_labels(gen_labels, len(a), model.num_classes, "gen_labels", "gen_x")
    return float((predict(model, a, batch_size) == lab).mean())


def confusion_matrix(model: ActionClassifier, x: Any, y: Any, batch_size: int = 512) -> np.ndarray:
    """``[C, C]`` int64 counts: row = true class ``y``, column = predicted class."""
    a = _as_motion(x, "x", model.input_size)
    lab = _as_labels(y, len(a), model.num_classes, "y", "x")
    C = model.num_classes
    return np.bincount(lab * C + predict(model, a, batch_size), minlength=C * C).reshape(C, C)


# --------------------------------------------------------------------------- training

def train_classifier(train_x: Any, train_y: Any, val_x: Any, val_y: Any, num_classes: int, epochs: int = 30,
                     batch_size: int = 64, lr: float = 1e-3, seed: int = 0, threads: int | None = 1,
                     hidden_size: int = 128, num_layers: int = 2, feature_size: int = 30, clip: float = 1.0,
                     max_batches_per_epoch: int | None = None, select: str = "val_acc", device: str = "cpu",
                     patience: int | None = None, dtype: str = "float32",
                     on_epoch: Callable[[dict, ActionClassifier], None] | None = None,
                     progress: bool = False) -> tuple[ActionClassifier, list[dict]]:
    """Train an :class:`ActionClassifier` on ``train_x`` ``[N, T, F]`` float32 with labels
    ``train_y`` ``[N]`` in ``[0, num_classes)``: cross-entropy, Adam(``lr``), shuffled batches of
    ``batch_size``, gradient norm clipped at ``clip`` (``None``: off), ``epochs`` epochs
    (``max_batches_per_epoch`` caps an epoch, taking the first batches of its shuffled order).

    ``val_x``/``val_y`` (may be ``None``) are never trained on; they are evaluated after every
    epoch and, by ``select``, choose the returned weights: ``"val_acc"`` the epoch with the
    highest val accuracy (ties: the lower val loss), ``"val_loss"`` the lowest val loss,
    ``"last"`` the last epoch (also what any choice gives without val data). They must come
    from the validation split, never the test split, which is reserved for :func:`accuracy`
    afterwards. ``patience`` (``None``: off) stops training once that many epochs in a row have not
    improved the selection key (with val data and ``select`` other than ``"last"``): the epochs after
    the selected one change nothing that is returned. ``dtype`` (``"float32"`` or ``"float64"``) is the
    precision of the weights and of every computation; inputs stay float32 and are cast per batch
    (float64: see "Precision" in the module docstring). ``threads`` sets ``torch.set_num_threads`` for the call (restored after;
    ``None`` leaves it). ``on_epoch(row, model)`` is called after each epoch (logging; it
    must not change the model). Returns ``(model in eval mode, history)``, history one dict
    per epoch: ``epoch, train_loss, train_acc`` (running, over the epoch's batches),
    ``val_loss, val_acc`` (when val data is given), ``seconds``; the selected epoch's dict has
    ``selected: True``.
    """
    if select not in ("val_acc", "val_loss", "last"):
        raise ValueError(f"select must be 'val_acc', 'val_loss' or 'last'; got {select!r}")
    if dtype not in DTYPES:
        raise ValueError(f"dtype must be one of {DTYPES}; got {dtype!r}")
    tdtype = getattr(torch, dtype)
    num_classes = _check_count(num_classes, "num_classes", 2)
    epochs = _check_count(epochs, "epochs")
    batch_size = _check_count(batch_size, "batch_size")
    if max_batches_per_epoch is not None:
        max_batches_per_epoch = _check_count(max_batches_per_epoch, "max_batches_per_epoch")
    if patience is not None:
        patience = _check_count(patience, "patience")
    if not (np.isfinite(lr) and lr > 0):
        raise ValueError(f"lr must be a positive number; got {lr!r}")
    if clip is not None and not (np.isfinite(clip) and clip > 0):
        raise ValueError(f"clip must be a positive number or None; got {clip!r}")
    x = _as_motion(train_x, "train_x")
    y = _as_labels(train_y, len(x), num_classes, "train_y", "train_x")
    has_val = val_x is not None
    if has_val != (val_y is not None):
        raise ValueError("give both val_x and val_y, or neither")
    if has_val:
        vx = _as_motion(val_x, "val_x", x.shape[2])
        vy = _as_labels(val_y, len(vx), num_classes, "val_y", "val_x")
    old_threads = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(_check_count(threads, "threads"))
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            model = ActionClassifier(x.shape[2], num_classes, hidden_size, num_layers, feature_size)
        model.to(device, tdtype)     # initialised in float32 (the same draws for either dtype), then cast
        opt = torch.optim.Adam(model.parameters(), lr=lr)
        loss_fn = nn.CrossEntropyLoss()
        history: list[dict] = []
        best_key, best_state = None, None
        for epoch in range(epochs):
            t0 = time.perf_counter()
            model.train()
            order = np.random.default_rng([seed, epoch]).permutation(len(x))
            batches = [order[s:s + batch_size] for s in range(0, len(x), batch_size)][:max_batches_per_epoch]
            tot_loss, tot_right, seen = 0.0, 0, 0
            for b in batches:
                xb, yb = torch.from_numpy(x[b]).to(device, tdtype), torch.from_numpy(y[b]).to(device)
                logits = model(xb)
                loss = loss_fn(logits, yb)
                opt.zero_grad()
                loss.backward()
                if clip is not None:
                    nn.utils.clip_grad_norm_(model.parameters(), clip)
                opt.step()
                tot_loss += loss.item() * len(b)
                tot_right += int((logits.argmax(1) == yb).sum())
                seen += len(b)
            row = {"epoch": epoch, "train_loss": tot_loss / seen, "train_acc": tot_right / seen}
            if has_val:
                vlogits = torch.from_numpy(_forward_batched(model, vx, model, 512))
                row["val_loss"] = float(loss_fn(vlogits, torch.from_numpy(vy)))
                row["val_acc"] = float((vlogits.argmax(1).numpy() == vy).mean())
            if has_val and select == "val_acc":
                key = (row["val_acc"], -row["val_loss"])       # larger is better
            elif has_val and select == "val_loss":
                key = (-row["val_loss"],)
            else:
                key = (epoch,)                                # the last epoch wins
            row["seconds"] = time.perf_counter() - t0
            history.append(row)
            if on_epoch is not None:
                on_epoch(row, model)
            if best_key is None or key > best_key:
                best_key, best_state, best_epoch = key, copy.deepcopy(model.state_dict()), epoch
            if progress:
                print(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()),
                      flush=True)
            if patience is not None and has_val and select != "last" and epoch - best_epoch >= patience:
                break                                         # the selected weights can no longer change
        model.load_state_dict(best_state)
        history[best_epoch]["selected"] = True
    finally:
        torch.set_num_threads(old_threads)
    return model.eval(), history


# --------------------------------------------------------------------------- FID

def feature_stats(feats: Any) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``[K]`` and covariance ``[K, K]`` (``ddof = 1``) of features ``[N, K]``, N >= 2, float64."""
    f = _as_feats(feats, "feats", min_rows=2)
    mu = f.mean(0)
    c = f - mu
    return mu, (c.T @ c) / (len(f) - 1)


def _psd_sqrt(s: np.ndarray) -> np.ndarray:
    """Symmetric square root of a symmetric PSD matrix (negative rounding eigenvalues -> 0)."""
    w, v = np.linalg.eigh(s)
    return (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T


def frechet_distance(mu1: Any, sigma1: Any, mu2: Any, sigma2: Any) -> float:
    """Fréchet distance between ``N(mu1, sigma1)`` and ``N(mu2, sigma2)``:
    ``||mu1 - mu2||^2 + Tr(S1 + S2 - 2 (S1 S2)^{1/2})`` (see the module docstring for the
    square-root route). ``mu`` ``[K]``, ``sigma`` ``[K, K]`` symmetric PSD."""
    mu1, mu2 = (np.asarray(m, dtype=np.float64) for m in (mu1, mu2))
    s1, s2 = (np.asarray(s, dtype=np.float64) for s in (sigma1, sigma2))
    if mu1.ndim != 1 or mu1.shape != mu2.shape:
        raise ValueError(f"means must be 1-D of equal length; got {mu1.shape} and {mu2.shape}")
    K = len(mu1)
    for name, s in (("sigma1", s1), ("sigma2", s2)):
        if s.shape != (K, K):
            raise ValueError(f"{name} must be [{K}, {K}] to match the means; got {s.shape}")
        if not np.isfinite(s).all():
            raise ValueError(f"{name} has non-finite values")
        if not np.allclose(s, s.T, rtol=1e-8, atol=1e-10 * max(1.0, float(np.abs(s).max()))):
            raise ValueError(f"{name} is not symmetric")
    if not (np.isfinite(mu1).all() and np.isfinite(mu2).all()):
        raise ValueError("means have non-finite values")
    s1, s2 = (s1 + s1.T) / 2, (s2 + s2.T) / 2
    r = _psd_sqrt(s1)
    m = r @ s2 @ r
    tr_sqrt = np.sqrt(np.clip(np.linalg.eigvalsh((m + m.T) / 2), 0.0, None)).sum()
    d = float(((mu1 - mu2) ** 2).sum() + np.trace(s1) + np.trace(s2) - 2.0 * tr_sqrt)
    return max(d, 0.0)


def fid(real_feats: Any, gen_feats: Any) -> float:
    """FID between real features ``[N_r, K]`` and generated features ``[N_g, K]`` (each N >= 2)."""
    r = _as_feats(real_feats, "real_feats", min_rows=2)
    g = _as_feats(gen_feats, "gen_feats", min_rows=2)
    if r.shape[1] != g.shape[1]:
        raise ValueError(f"real_feats and gen_feats have different feature sizes: {r.shape[1]} vs {g.shape[1]}")
    return frechet_distance(*feature_stats(r), *feature_stats(g))


# --------------------------------------------------------------------------- diversity, multimodality

def _pair_distance(f: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    return np.sqrt(((f[i] - f[j]) ** 2).sum(-1))


def _draw_second(rng: np.random.Generator, first: np.ndarray, n: np.ndarray | int, distinct: bool) -> np.ndarray:
    """Second index in ``[0, n)``: uniform, or uniform over the ``n - 1`` values != ``first``."""
    if distinct:
        return (first + 1 + rng.integers(0, np.asarray(n) - 1, size=first.shape)) % n
    return rng.integers(0, n, size=first.shape)


def diversity(feats: Any, pairs: int = DIVERSITY_PAIRS, seed: int = 0, distinct: bool = False) -> float:
    """Mean L2 distance between ``pairs`` (S_d) random pairs of the feature rows ``[N, K]``
    (indices uniform with replacement; ``distinct=True``: the two indices differ). N >= 2."""
    pairs = _check_count(pairs, "pairs")
    f = _as_feats(feats, "feats")
    if len(f) < 2:
        raise ValueError(f"diversity needs at least 2 samples to form a pair; got {len(f)}")
    rng = np.random.default_rng(seed)
    i = rng.integers(0, len(f), size=pairs)
    j = _draw_second(rng, i, len(f), distinct)
    return float(_pair_distance(f, i, j).mean())


def multimodality_per_class(feats: Any, labels: Any, pairs: int = MULTIMODALITY_PAIRS, seed: int = 0,
                            num_classes: int | None = None, distinct: bool = False,
                            skip_small: bool = False) -> dict[int, float]:
    """``{class: mean L2 distance of its `pairs` (S_l) random same-class pairs}``.

    Classes are ``0..num_classes-1`` when ``num_classes`` is given (so a class without any
    sample counts as too small), else the distinct values of ``labels`` ``[N]``. A class
    with fewer than 2 samples raises ``ValueError`` or, with ``skip_small``, is left out of
    the dict. All classes are drawn in one vectorised step from ``default_rng(seed)``.
    """
    pairs = _check_count(pairs, "pairs")
    f = _as_feats(feats, "feats")
    if num_classes is not None:
        num_classes = _check_count(num_classes, "num_classes")
    lab = _as_labels(labels, len(f), num_classes, "labels", "feats")
    classes = np.arange(num_classes) if num_classes is not None else np.unique(lab)
    counts = np.bincount(lab, minlength=int(classes.max()) + 1)[classes]          # [C]
    small = counts < 2
    if small.any() and not skip_small:
        raise ValueError(f"multimodality needs >= 2 samples in every class; classes "
                         f"{classes[small].tolist()} have {counts[small].tolist()} (pass skip_small=True "
                         f"to leave them out)")
    classes, counts = classes[~small], counts[~small]
    if len(classes) == 0:
        raise ValueError("multimodality: no class has >= 2 samples")
    order = np.argsort(lab, kind="stable")                                        # samples grouped by class
    starts = np.concatenate([[0], np.cumsum(np.bincount(lab))])[classes]           # [C] first row of each class
    rng = np.random.default_rng(seed)
    n = counts[:, None]                                                            # [C, 1]
    i = rng.integers(0, n, size=(len(classes), pairs))                            # [C, S_l] within-class indices
    j = _draw_second(rng, i, n, distinct)
    d = _pair_distance(f, order[starts[:, None] + i], order[starts[:, None] + j])  # [C, S_l]
    return {int(c): float(v) for c, v in zip(classes, d.mean(1))}


def multimodality(feats: Any, labels: Any, pairs: int = MULTIMODALITY_PAIRS, seed: int = 0,
                  num_classes: int | None = None, distinct: bool = False, skip_small: bool = False) -> float:
    """Mean over classes of :func:`multimodality_per_class` (Action2Motion's MModality)."""
    per = multimodality_per_class(feats, labels, pairs, seed, num_classes, distinct, skip_small)
    return float(np.mean(list(per.values())))


# --------------------------------------------------------------------------- all at once

def generative_metrics(model: ActionClassifier, real_x: Any, real_labels: Any, gen_x: Any, gen_labels: Any,
                       seed: int = 0, diversity_pairs: int = DIVERSITY_PAIRS,
                       multimodality_pairs: int = MULTIMODALITY_PAIRS, skip_small: bool = False,
                       batch_size: int = 512) -> dict[str, float]:
    """FID, accuracy, diversity and multimodality of generated motions ``gen_x`` ``[N_g, T, F]``
    (classes ``gen_labels`` ``[N_g]``) against real motions ``real_x`` ``[N_r, T, F]``, and the
    same three per-set metrics of the real motions (the "Real" row of Action2Motion's tables).
    Multimodality runs over the classes present in each set's labels."""
    r = _as_motion(real_x, "real_x", model.input_size)
    g = _as_motion(gen_x, "gen_x", model.input_size)
    rl = _as_labels(real_labels, len(r), model.num_classes, "real_labels", "real_x")
    gl = _as_labels(gen_labels, len(g), model.num_classes, "gen_labels", "gen_x")
    fr, fg = features(model, r, batch_size), features(model, g, batch_size)
    return {
        "fid": fid(fr, fg),
        "accuracy": recognition_accuracy(model, g, gl, batch_size),
        "diversity": diversity(fg, diversity_pairs, seed),
        "multimodality": multimodality(fg, gl, multimodality_pairs, seed, skip_small=skip_small),
        "real_accuracy": accuracy(model, r, rl, batch_size),
        "real_diversity": diversity(fr, diversity_pairs, seed),
        "real_multimodality": multimodality(fr, rl, multimodality_pairs, seed, skip_small=skip_small),
        "n_real": float(len(r)),
        "n_gen": float(len(g)),
    }
