"""c-SkeletonGAN: smooth latent transitions with an action classifier (Wang et al., AAAI 2020,
arXiv 1912.10150, "Learning diverse stochastic human-action generators by learning smooth latent
transitions"); GlocalNet Table 3's second-strongest row.

The generator is SkeletonGAN's (:mod:`.skeleton_gan`): a shared pose decoder pretrained as a
class-conditional WGAN-GP on single poses, then a latent walk (``z_t = z_{t-1} + dz_t``, steps from an
LSTM over noise and the class: the "implicit RNN" of smooth latent transitions) trained against a
bi-directional LSTM sequence discriminator. What the authors' code
(zheshiyige/Learning-Diverse-Stochastic-Human-Action-Generators-by-Learning-Smooth-Latent-Transitions,
``model.py``, ``ops.py``) adds, and this file implements:

* an **action classifier** ``C``: a bi-directional LSTM (``classifier_hidden`` 256 per direction) over
  ``[x_t, x_{t+1} - x_t]`` (no class input), every step's output concatenated, ``-> width -> ReLU ->``
  class logits. It is trained with the generator (the same optimiser, the code's scope), on real and
  generated clips, weight ``classifier_weight`` (0.01): the generated clips must be recognisable as
  their class, the "bi-directional" / cycle-consistency part the abstract describes;
* the smoothness term on the generated poses, ``smooth_weight`` 1e-4 (the summed squared frame-to-
  frame differences, mean over the batch).

Everything else (sizes, two stages, Adam (0.5, 0.9), lr 1e-3 then 1e-4, 1 discriminator and 2
generator updates per iteration, batch 32) is SkeletonGAN's, as in the code; our budgets and
selection are :mod:`.skeleton_gan`'s and :mod:`.adversarial`'s. The paper's body was not available to
us: no equation numbers are cited.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .adversarial import _count
from .base import DataSpec
from .skeleton_gan import SequenceCritic, SkeletonGAN


class CSkeletonGAN(SkeletonGAN):
    """c-SkeletonGAN (module docstring): SkeletonGAN plus the classifier term. Hyperparameters: those of
    :class:`~.skeleton_gan.SkeletonGAN`, ``classifier_hidden`` and ``classifier_weight``."""

    def __init__(self, spec: DataSpec, classifier_hidden: int = 256, classifier_weight: float = 0.01,
                 smooth_weight: float = 1e-4, **kwargs):
        super().__init__(spec, smooth_weight=smooth_weight, **kwargs)
        _count("classifier_hidden", classifier_hidden, 1)
        if isinstance(classifier_weight, bool) or not isinstance(classifier_weight, (int, float)) \
                or not classifier_weight >= 0:
            raise ValueError(f"classifier_weight must be a number >= 0, got {classifier_weight!r}")
        self.classifier_weight = float(classifier_weight)
        width = self.critic.head[0].out_features
        # the classifier reads no class: a sequence critic without it, with a class head instead of one logit
        self.classifier = SequenceCritic(spec.pose_features, 0, self.clip, classifier_hidden, width)
        self.classifier.head[-1] = nn.Linear(width, self.num_classes)
        nn.init.normal_(self.classifier.head[-1].weight, 0.0, 0.02)
        nn.init.zeros_(self.classifier.head[-1].bias)

    def players(self) -> dict[str, list[nn.Parameter]]:
        p = super().players()
        p["generator"] = p["generator"] + list(self.classifier.parameters())    # trained with the walk (the code's)
        return p

    def classify(self, x: Tensor) -> Tensor:
        """Class logits ``[N, C]`` of clips ``[N, T, J, D]``."""
        x = x.flatten(2)
        h, _ = self.classifier.lstm(torch.cat([x[:, :-1], x[:, 1:] - x[:, :-1]], -1))
        return self.classifier.head(h.flatten(1))

    def generator_terms(self, fake: Tensor, dz: Tensor, real: Tensor, onehot: Tensor, labels: Tensor) -> dict[str, Tensor]:
        terms = super().generator_terms(fake, dz, real, onehot, labels)
        terms["classify"] = self.classifier_weight * (F.cross_entropy(self.classify(real), labels)
                                                      + F.cross_entropy(self.classify(fake), labels))
        return terms
