"""att. Seq2Seq: Seq2Seq whose decoder attends over every encoder state (GlocalNet Table 1's row).

The GlocalNet paper (Battan et al. 2021, Table 1, ref. [28]) compares against a sequence-to-
sequence motion model with attention, and its Sec. 5 contrasts that with GloGen, which hands
*all* encoder outputs to its decoder. The row's own paper gives no motion-specific recipe, so this
is :class:`~.seq2seq.Seq2Seq` (Martinez et al. 2017: one tied GRU, residual velocity,
sampling-based loss) with Luong-style attention over the encoder's states:

    H = [h_1 .. h_S]                                  encoder states over the S seed frames (ground truth)
    q_t = W_q h_t,  K = W_k H                          queries / keys, size ``attention_size``
    a_t = softmax(q_t K^T / sqrt(attention_size))     one weight per encoder state and output step
    c_t = a_t H                                        context
    x^_{t+1} = x_in_t + f_dec(tanh(W_c [h_t; c_t]))   residual output from the attentional state

Every output step (the encoder's last state, which predicts the first frame after the seed,
and every decoder step) attends over all ``S`` encoder states; :attr:`last_attention` keeps the
weights ``[B, steps, S]`` of the latest roll-out for inspection.

Choices that are ours (the papers give none):

* scaled dot-product scores with learnt query and key maps (values are the states themselves);
* the attentional state ``tanh(W_c [h_t; c_t])`` feeds the residual output layer only, not the
  next step's input (Luong et al. 2015's "input feeding" is not used: the decoder input stays
  the fed-back frame, as in Seq2Seq);
* as in :class:`~.seq2seq.Seq2Seq`, the output layer starts at zero (an untrained model is
  zero-velocity), and the encoder/decoder GRU is tied;
* only the sampling-based loss: ``scheduled_sampling`` is refused (its per-sample masks would mix
  encoder and decoder steps);
* Seq2Seq's training loss weighted ``1/h`` per predicted frame (``horizon_power: 1``, inherited from
  ``conf/model/seq2seq.yaml``): on validation it lowered ``rel_zv`` on ``cmu_aclstm`` and ``bandai1``
  for both seeds tried (``conf/model/att_seq2seq.yaml``).

Shapes: ``pose`` ``[B, T, J, D]`` -> encoder states ``[B, S, H]`` -> attention ``[B, steps, S]``
-> outputs ``[B, T-1, Fy]`` (frames ``1..T-1``; the loss reads frames ``S..``).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from .base import DataSpec
from .recurrent import MODULE_RUN, check_int, mask_seed_length
from .seq2seq import Seq2Seq


class AttSeq2Seq(Seq2Seq):

    @classmethod
    def check_hparams(cls, hparams: dict) -> None:
        """The names (:meth:`MotionModel.check_hparams`), ``attention_size`` >= 1, and no scheduled
        sampling; :func:`motionsynth.training.run.build` calls this before any data is read."""
        super().check_hparams(hparams)
        if "attention_size" in hparams:
            check_int("attention_size", hparams["attention_size"])
        if hparams.get("scheduled_sampling"):
            raise ValueError("att_seq2seq: scheduled_sampling must be false (the decoder attends over a "
                             "ground-truth encoder: only the sampling-based loss is supported)")

    def __init__(self, spec: DataSpec, hidden_size: int = 1024, num_layers: int = 1, attention_size: int = 128,
                 **kwargs):
        self.check_hparams({"attention_size": attention_size, **kwargs})
        super().__init__(spec, hidden_size, num_layers, **kwargs)
        self.attention_size = attention_size
        self.att_query = nn.Linear(hidden_size, attention_size, bias=False)
        self.att_key = nn.Linear(hidden_size, attention_size, bias=False)
        self.att_combine = nn.Linear(2 * hidden_size, hidden_size)
        self.last_attention: Tensor | None = None

    def _attend(self, h: Tensor, keys: Tensor, states: Tensor, s: Tensor) -> tuple[Tensor, Tensor]:
        """Outputs and weights of the steps ``h`` ``[B, L, H]`` (inputs ``s`` ``[B, L, Fy]``) over the
        encoder's ``states`` ``[B, S, H]`` (their ``keys`` ``[B, S, A]``)."""
        scores = self.att_query(h) @ keys.transpose(1, 2) / math.sqrt(self.attention_size)   # [B, L, S]
        w = torch.softmax(scores, -1)
        ctx = w @ states                                                                     # [B, L, H]
        a = torch.tanh(self.att_combine(torch.cat([h, ctx], -1)))
        return self.decoder(a) + s, w

    def _rollout(self, inp: Tensor, cond: Tensor | None, mask: Tensor | None) -> Tensor:
        """As :meth:`RecurrentBaseline._rollout` for Seq2Seq's mask (a ground-truth seed, then
        self-fed steps), with every output attending over the seed's encoder states."""
        B, N, _ = inp.shape
        S = mask_seed_length(mask, "att_seq2seq")
        grad = torch.is_grad_enabled()
        x = inp[:, :S] if cond is None else torch.cat([inp[:, :S], cond[:, :S]], -1)
        step = self.core.stepper() if (S < N or (grad and S < MODULE_RUN)) else None
        if grad and S < MODULE_RUN:
            states, state = step.run(self.encoder(x), self.core.zero_state(B, inp))
        else:
            states, state = self.core.sequence(self.encoder(x), None)
        keys = self.att_key(states)
        out, w = self._attend(states, keys, states, inp[:, :S])
        outs, weights = [out], [w]
        prev = out[:, -1]
        for t in range(S, N):
            xt = prev if cond is None else torch.cat([prev, cond[:, t]], -1)
            h, state = step(self.encoder(xt), state)
            o, w = self._attend(h[:, None], keys, states, prev[:, None])
            prev = o[:, 0]
            outs.append(o)
            weights.append(w)
        self.last_attention = torch.cat(weights, 1).detach()
        return torch.cat(outs, 1)
