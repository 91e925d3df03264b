"""ERD: Encoder-Recurrent-Decoder (Fragkiadaki, Levine, Felsen, Malik, ICCV 2015).

Paper, Sec. 3 and the mocap instantiation of Sec. 4.1: a nonlinear encoder (two fully
connected layers, 500 and 500 units), a two-layer LSTM (1000 units each) and a nonlinear
decoder (two fully connected layers, 100 units then the frame's dimensions), trained to
predict the next frame with a Euclidean loss under teacher forcing:

    e_t = f_enc(x_t);  h_t = LSTM(e_t, h_{t-1});  x^_{t+1} = f_dec(h_t);  L = sum_t ||x^_{t+1} - x_{t+1}||^2

Choices where the paper is vague (all in :mod:`.recurrent`):

* activations: ReLU after both encoder layers and between the decoder layers, a linear
  output layer (the paper names the layer sizes only);
* the input-noise curriculum of the mocap experiments (Gaussian noise on the inputs, its std raised
  during training so the network learns to correct its own drift) is ``input_noise``: a
  list of stds, each used for an equal share of the training budget; off by default, on in the ``paper``
  preset (levels ours: the paper gives no schedule in epochs);
* the mean squared error over frames and features replaces the summed squared error
  (a constant factor);
* features, control modes, seed protocol and the ``family`` choice are those of
  :class:`~.recurrent.RecurrentBaseline`.

Departure (ours, ``residual: true`` in ``training.model_overrides`` of ``conf/dataset/bandai2_locomotion.yaml``
and ``h36m.yaml``): there the decoder predicts the change from the frame fed in, ``x^_{t+1} = x_t + f_dec(h_t)``, its last
layer starting at zero (:class:`~.recurrent.RecurrentBaseline`'s ``residual``; Martinez et al.'s residual
velocity), so training starts from zero-velocity instead of learning the identity. Validation ``rel_zv``
at the same budget: ``bandai2_locomotion`` 0.214 -> 0.146 and, with given controls, 0.291 -> 0.183; ``h36m``
1.57 -> 0.508 (worse than zero-velocity before); all converged. On ``cmu_aclstm`` and ``bandai1`` too
(``residual: true`` in their configs), where the residual model learns in a few hundred steps and then drifts
as it trains on: validated every 45 steps with patience 6 (``conf/model/erd.yaml``) it selects 0.789 at step
135 and 0.659 at step 225, against 0.994 and 1.18 for the pose output at 4,500 steps (README, *Departures*).

Shapes: ``pose`` ``[B, T, J, D]`` -> inputs ``[B, T-1, Fy+Fc]`` -> encoder ``[B, T-1, 500]``
-> LSTM ``[B, T-1, 1000]`` -> decoder ``[B, T-1, Fy]`` (frames ``1..T-1``).
"""

from __future__ import annotations

from typing import Sequence

from .base import DataSpec
from .recurrent import RecurrentBaseline


class ERD(RecurrentBaseline):
    cell = "lstm"

    def __init__(self, spec: DataSpec, hidden_size: int = 1000, num_layers: int = 2,
                 encoder_sizes: Sequence[int] = (500, 500), decoder_hidden: int = 100, **common):
        super().__init__(spec, hidden_size, num_layers, encoder_sizes=encoder_sizes,
                         decoder_sizes=(decoder_hidden,), **common)
