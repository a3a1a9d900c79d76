"""The EpO+ fusion network: appearance bottleneck, motion map, bidirectional ConvGRU, per-frame classifier.

Paper section 4.3 (and section 5.2 for the initialisation); the cell follows the authors' ``ConvGRU.lua``
(see ``original-implementation.md`` section 9.2), itself modelled on LVO (Tokmakov et al., ICCV 2017).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["ConvGRUCell", "ConvGRUFusion", "resize_saliency"]


class ConvGRUCell(nn.Module):
    """A convolutional GRU cell with ``hidden`` state channels and ``kernel_size`` x ``kernel_size`` kernels.

    With input ``x_t`` and previous state ``s`` (zeros before the first frame)::

        r   = sigmoid(conv_x^r(x_t) + conv_s^r(s))          reset gate
        z   = sigmoid(conv_x^z(x_t) + conv_s^z(s))          update gate
        c   = tanh(conv_x^c(x_t) + conv_s^c(r * s))         candidate
        s_t = (1 - z) * c + z * s

    The ``conv_x`` convolutions have biases, the ``conv_s`` ones do not; all use stride 1 and "same" padding.
    Initialisation (paper section 5.2): He (MSR) normal weights; biases 0 except the update gate's input bias,
    which is 1 (``initBias(forgetBias=1)`` in the authors' code), so that a fresh cell starts by mostly
    keeping its state.
    """

    def __init__(self, in_channels: int, hidden: int, kernel_size: int = 3):
        super().__init__()
        if kernel_size < 1 or kernel_size % 2 == 0:
            raise ValueError(f"kernel_size: expected an odd positive integer, got {kernel_size}")
        self.hidden = hidden
        pad = kernel_size // 2
        # The input convolutions of the three gates (r, z, c) are one convolution: they can run on every frame
        # of a sequence at once, before the recurrence.
        self.input_conv = nn.Conv2d(in_channels, 3 * hidden, kernel_size, padding=pad)
        self.state_gates = nn.Conv2d(hidden, 2 * hidden, kernel_size, padding=pad, bias=False)
        self.state_candidate = nn.Conv2d(hidden, hidden, kernel_size, padding=pad, bias=False)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        for conv in (self.input_conv, self.state_gates, self.state_candidate):
            nn.init.kaiming_normal_(conv.weight, nonlinearity="relu")
        with torch.no_grad():
            self.input_conv.bias.zero_()
            self.input_conv.bias[self.hidden : 2 * self.hidden] = 1.0

    def gate_biases(self) -> dict[str, torch.Tensor]:
        """The input biases of the reset, update and candidate convolutions, each ``(hidden,)``."""
        bias = self.input_conv.bias
        h = self.hidden
        return {"reset": bias[:h], "update": bias[h : 2 * h], "candidate": bias[2 * h :]}

    def forward(self, x: torch.Tensor, *, reverse: bool = False) -> torch.Tensor:
        """States ``(B, T, hidden, h, w)`` of a pass over ``x`` ``(B, T, C, h, w)``, in time order or, with
        ``reverse``, from the last frame to the first (the states are still returned in time order)."""
        batch, steps = x.shape[:2]
        gates_x = self.input_conv(x.flatten(0, 1)).unflatten(0, (batch, steps))
        state = x.new_zeros((batch, self.hidden) + tuple(x.shape[-2:]))
        states: list[torch.Tensor] = [state] * steps
        h = self.hidden
        for t in reversed(range(steps)) if reverse else range(steps):
            g = gates_x[:, t]
            rz = torch.sigmoid(g[:, : 2 * h] + self.state_gates(state))
            reset, update = rz[:, :h], rz[:, h:]
            candidate = torch.tanh(g[:, 2 * h :] + self.state_candidate(reset * state))
            state = (1 - update) * candidate + update * state
            states[t] = state
        return torch.stack(states, dim=1)


def resize_saliency(saliency: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Bilinearly resize motion saliency maps ``(B, T, H, W)`` to ``size`` ``(h, w)`` (antialiased when
    shrinking, so a thin object is averaged rather than skipped)."""
    if tuple(saliency.shape[-2:]) == tuple(size):
        return saliency
    batch, steps = saliency.shape[:2]
    flat = saliency.flatten(0, 1)[:, None]
    shrink = size[0] < flat.shape[-2] or size[1] < flat.shape[-1]
    out = F.interpolate(flat, size=size, mode="bilinear", align_corners=False, antialias=shrink)
    return out[:, 0].unflatten(0, (batch, steps))


class ConvGRUFusion(nn.Module):
    """EpO+ fusion (paper section 4.3): appearance features and the motion saliency map of each frame go
    through a bidirectional ConvGRU; a per-frame classifier reads both directions' states.

    1. a trained 1x1 bottleneck maps the ``appearance_channels`` feature channels to ``bottleneck`` channels
       (1024 -> 128 in the paper), followed by a ReLU; with ``appearance_channels=0`` (the ``none`` appearance
       stage, motion only) there is no bottleneck;
    2. the motion saliency map, resized to the feature size, is concatenated as one more channel;
    3. a forward and a backward :class:`ConvGRUCell` (separate weights, ``hidden`` channels, ``kernel_size``)
       run over the sequence;
    4. the classifier is a 1x1 convolution of the concatenated states, written as the sum of one 1x1
       convolution per direction and a shared bias (the same function; the split makes the direction swap of
       the tests exact);
    5. :meth:`frame_logits` upsamples the logits to the frame size. With ``motion_residual`` (an eponet
       extension, off in the paper's network) the network predicts a correction of the motion net: the output
       is ``up(logits) + motion_weight * logit(s)`` with ``s`` the full-resolution motion map clipped to
       [1e-3, 1 - 1e-3], ``motion_weight`` learned from 1 and the classifier starting at zero, so training
       starts from EpO's own prediction and boundaries keep the motion map's resolution. A frame whose motion
       map is all zero (input-dropout) gets no residual: there the appearance and memory must do the work.

    ``feature_dropout`` (eponet extension; 0 in the paper) drops whole appearance channels with that
    probability in training (``nn.Dropout2d`` before the bottleneck), against over-fitting the few training
    sequences' appearance.

    Initialisation (paper section 5.2): Xavier for the bottleneck and classifier, He for the ConvGRU.

    Input: ``features`` float ``(B, T, C, h, w)`` and ``saliency`` float ``(B, T, H, W)`` in [0, 1] (any size;
    resized to ``(h, w)``). Output: logits ``(B, T, h, w)`` at the feature size; :meth:`frame_logits` brings
    them to the frame size (apply a sigmoid for the foreground probability).
    """

    #: Motion maps are clipped to [MOTION_EPS, 1 - MOTION_EPS] before their logit is taken (residual: +-6.9).
    MOTION_EPS = 1e-3

    def __init__(self, appearance_channels: int, *, bottleneck: int = 128, hidden: int = 64, kernel_size: int = 3,
                 motion_residual: bool = False, feature_dropout: float = 0.0):
        super().__init__()
        if appearance_channels < 0 or bottleneck < 1 or hidden < 1:
            raise ValueError(f"expected appearance_channels >= 0, bottleneck >= 1 and hidden >= 1, got "
                             f"{appearance_channels}, {bottleneck}, {hidden}")
        self.config = {"appearance_channels": appearance_channels, "bottleneck": bottleneck, "hidden": hidden,
                       "kernel_size": kernel_size, "motion_residual": bool(motion_residual),
                       "feature_dropout": float(feature_dropout)}
        self.bottleneck = nn.Conv2d(appearance_channels, bottleneck, 1) if appearance_channels else None
        self.feature_dropout = nn.Dropout2d(feature_dropout) if feature_dropout > 0 else nn.Identity()
        gru_in = (bottleneck if appearance_channels else 0) + 1
        self.forward_cell = ConvGRUCell(gru_in, hidden, kernel_size)
        self.backward_cell = ConvGRUCell(gru_in, hidden, kernel_size)
        self.head_forward = nn.Conv2d(hidden, 1, 1, bias=False)
        self.head_backward = nn.Conv2d(hidden, 1, 1, bias=False)
        self.head_bias = nn.Parameter(torch.zeros(1))
        self.motion = nn.Parameter(torch.ones(1)) if motion_residual else None
        for conv in (self.bottleneck, self.head_forward, self.head_backward):
            if conv is not None:
                nn.init.xavier_uniform_(conv.weight)
                if conv.bias is not None:
                    nn.init.zeros_(conv.bias)
        if motion_residual:  # start from the motion net's own prediction
            nn.init.zeros_(self.head_forward.weight)
            nn.init.zeros_(self.head_backward.weight)

    @property
    def appearance_channels(self) -> int:
        return self.config["appearance_channels"]

    def inputs(self, features: torch.Tensor, saliency: torch.Tensor) -> torch.Tensor:
        """The ConvGRU input ``(B, T, bottleneck + 1, h, w)`` (bottleneck features, then the motion map)."""
        if features.ndim != 5 or features.shape[2] != self.appearance_channels:
            raise ValueError(f"features: expected (B, T, {self.appearance_channels}, h, w), got {tuple(features.shape)}")
        if saliency.ndim != 4 or saliency.shape[:2] != features.shape[:2]:
            raise ValueError(f"saliency: expected (B, T, H, W) with B, T = {tuple(features.shape[:2])}, "
                             f"got {tuple(saliency.shape)}")
        batch, steps = features.shape[:2]
        motion = resize_saliency(saliency.to(features.dtype), tuple(features.shape[-2:]))[:, :, None]
        if self.bottleneck is None:
            return motion
        reduced = F.relu(self.bottleneck(self.feature_dropout(features.flatten(0, 1)))).unflatten(0, (batch, steps))
        return torch.cat([reduced, motion], dim=2)

    def forward(self, features: torch.Tensor, saliency: torch.Tensor) -> torch.Tensor:
        x = self.inputs(features, saliency)
        forward_states = self.forward_cell(x)
        backward_states = self.backward_cell(x, reverse=True)
        batch, steps = x.shape[:2]
        logits = (self.head_forward(forward_states.flatten(0, 1))
                  + self.head_backward(backward_states.flatten(0, 1))) + self.head_bias
        return logits[:, 0].unflatten(0, (batch, steps))

    @property
    def motion_weight(self) -> float:
        """The weight of the motion map's logit in :meth:`frame_logits` (0 without ``motion_residual``)."""
        return float(self.motion.detach()) if self.motion is not None else 0.0

    def frame_logits(self, logits: torch.Tensor, saliency: torch.Tensor) -> torch.Tensor:
        """Logits ``(N, H, W)`` at the frame size from logits ``(N, h, w)`` at the feature size and the motion
        maps ``(N, H, W)`` in [0, 1] that went in: bilinear upsampling, plus the motion map's logit with
        ``motion_residual`` (see the class documentation)."""
        out = F.interpolate(logits[:, None], size=tuple(saliency.shape[-2:]), mode="bilinear", align_corners=False)[:, 0]
        if self.motion is None:
            return out
        saliency = saliency.to(out.dtype)
        present = (saliency.flatten(1).amax(1) > 0).to(out.dtype)[:, None, None]
        return out + self.motion * present * torch.logit(saliency, eps=self.MOTION_EPS)
