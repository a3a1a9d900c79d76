"""The EpO motion network: a U-Net on motion images (paper section 4.2)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from eponet.core.motion import ED_ENCODINGS, FLOW_CENTRINGS, FLOW_SCALE, encode_ed, flow_spread_problem

__all__ = ["EpoUNet", "INPUT_CHANNELS", "FLOW_CENTRINGS", "InferenceUNet", "affine_flow_residual", "centre_flow",
           "flow_spread"]

#: Which channels of a (dx, dy, ED) motion image each input modality uses.
INPUT_CHANNELS = {"ed+flow": (0, 1, 2), "flow": (0, 1), "ed": (2,)}



def _rigid_pixels(ed: torch.Tensor) -> torch.Tensor:
    """``(B, N)`` bool: the pixels of each frame whose ED ``(B, N)`` is at most the frame's median ED."""
    return ed <= ed.median(dim=1, keepdim=True).values


def centre_flow(motion_images: torch.Tensor) -> torch.Tensor:
    """(dx, dy, ED) motion images ``(B, 3, H, W)`` with each frame's flow channels less the median flow of its
    pixels whose ED is at most the frame's median ED: the flow of the part of the frame that the epipolar geometry
    finds most rigid, so that a camera that pans or follows an object gives that part a flow near zero and the
    object its motion relative to it. Where ED is constant (a zeroed ED channel) that is the median over the frame.
    A new tensor; the ED channel is unchanged."""
    flow = motion_images[:, :2].flatten(2)
    rigid = _rigid_pixels(motion_images[:, 2].flatten(1))
    reference = flow.masked_fill(~rigid[:, None], float("nan")).nanmedian(dim=2).values
    out = motion_images.clone()
    out[:, :2] -= reference[:, :, None, None]
    return out


def affine_flow_residual(motion_images: torch.Tensor, refits: int = 1) -> torch.Tensor:
    """(dx, dy, ED) motion images ``(B, 3, H, W)`` with each frame's flow channels less an affine flow field
    ``(dx, dy) = A (x, y, 1)`` fitted by least squares to the pixels whose ED is at most the frame's median ED,
    then refitted ``refits`` times to those of them whose residual is at most their median residual (a trimmed
    fit: the rigid part's own outliers, e.g. parallax of near objects, leave it). A camera that pans, tilts,
    rolls or zooms over a distant scene moves its pixels by nearly such a field (a homography's first-order
    terms), so what is left is the object's motion relative to the scene, near zero on the scene, where
    :func:`centre_flow` removes only the translation. ``x, y`` run over [-1, 1] across the frame, so the fit does
    not depend on its size. Where ED is constant (a zeroed ED channel) the fit is over the whole frame.
    A new tensor; the ED channel is unchanged."""
    b, _, h, w = motion_images.shape
    flow = motion_images[:, :2].flatten(2).float()  # (B, 2, N)
    gy, gx = torch.meshgrid(torch.linspace(-1.0, 1.0, h), torch.linspace(-1.0, 1.0, w), indexing="ij")
    basis = torch.stack([gx.flatten(), gy.flatten(), torch.ones(h * w)], dim=1).to(flow.device)  # (N, 3)
    rigid = _rigid_pixels(motion_images[:, 2].flatten(1))
    used = rigid
    ridge = 1e-6 * torch.eye(3, device=flow.device)
    for step in range(refits + 1):
        weight = used.float()
        normal = torch.einsum("bn,ni,nj->bij", weight, basis, basis) + ridge  # (B, 3, 3)
        rhs = torch.einsum("bn,ni,bcn->bic", weight, basis, flow)  # (B, 3, 2)
        coefficients = torch.linalg.solve(normal, rhs)  # (B, 3, 2)
        residual = flow - torch.einsum("ni,bic->bcn", basis, coefficients)
        if step < refits:
            size = residual.norm(dim=1).masked_fill(~rigid, float("nan"))
            used = rigid & (size <= size.nanmedian(dim=1, keepdim=True).values)
    out = motion_images.clone()
    out[:, :2] = residual.view(b, 2, h, w).to(out.dtype)
    return out


def flow_spread(motion_images: torch.Tensor, window: int) -> torch.Tensor:
    """How incoherent the flow is around each pixel: ``ln(1 + s)`` with ``s`` the standard deviation in pixels (of
    the processing resolution) of the flow vectors in the ``window`` x ``window`` pixels around it,
    ``s = sqrt(var(dx) + var(dy))`` (the window cut at the frame's border). Float ``(B, 1, H, W)`` from (dx, dy, ED)
    motion images ``(B, 3, H, W)``.

    Near 0 inside anything that moves as one piece (a rigid background, an object's body, whatever the camera
    does: a flow nearly constant across the window), large on dynamic texture (water, spray, smoke, foliage),
    where the flow of neighbouring pixels disagrees, and along motion boundaries. Unchanged by a constant added to
    the flow (a pan, :func:`centre_flow`) and by a left-right mirror.
    """
    flow = motion_images[:, :2].float() * FLOW_SCALE
    flow = flow - flow.mean(dim=(2, 3), keepdim=True)  # the same spread, smaller sums of squares
    height, width = flow.shape[-2:]
    sums = _box_sums(torch.cat([flow, flow * flow], dim=1), window)
    means = sums / (_window_counts(height, window, flow.device)[:, None] * _window_counts(width, window, flow.device))
    variance = (means[:, 2:] - means[:, :2] ** 2).clamp_(min=0.0).sum(dim=1, keepdim=True)
    return torch.log1p(variance.sqrt_()).to(motion_images.dtype)


def _window_counts(size: int, window: int, device) -> torch.Tensor:
    """Float ``(size,)``: how many of the ``window`` positions centred on each index lie inside ``0 .. size - 1``."""
    index = torch.arange(size, device=device)
    half = window // 2
    return ((index + half).clamp(max=size - 1) - (index - half).clamp(min=0) + 1).float()


def _box_sums(x: torch.Tensor, window: int) -> torch.Tensor:
    """Sums of ``x`` ``(B, C, H, W)`` over the ``window`` x ``window`` pixels around each pixel (zeros beyond the
    border), one axis at a time as sums of shifted views: ``avg_pool2d`` at stride 1 cost several times more (about
    as much as the network), and differences of cumulative sums lose float32 precision along a frame's rows."""
    half = window // 2
    for dim, pad in ((3, (half, half)), (2, (0, 0, half, half))):
        size = x.shape[dim]
        padded = F.pad(x, pad)
        total = padded.narrow(dim, 0, size).clone()
        for shift in range(1, window):
            total += padded.narrow(dim, shift, size)
        x = total
    return x


#: What ``flow_centring`` subtracts from the flow channels (:data:`eponet.core.motion.FLOW_CENTRINGS`).
_CENTRING = {"rigid": centre_flow, "affine": affine_flow_residual}

#: Pixels per block of :class:`InferenceUNet`'s head (its hidden layer, 4096 x 32 floats, fits a core's cache).
HEAD_BLOCK = 4096


def _conv_bn_relu(cin: int, cout: int, kernel: int = 3) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, kernel, padding=kernel // 2, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class EpoUNet(nn.Module):
    """U-Net of the paper: ``depth`` encoder blocks (conv, BatchNorm, ReLU, max-pool), a bottleneck block,
    ``depth`` decoder blocks (bilinear upsampling to the skip's size, concatenation, conv, BatchNorm, ReLU),
    a 1x1 layer to ``head_channels`` (128 in the paper) and a 1x1 classifier.

    Input: float ``(B, C, H, W)`` with C = ``len(INPUT_CHANNELS[inputs])``; any H, W (not only multiples of
    2**depth: the decoder resizes to each skip's size). Output: logits ``(B, 1, H, W)``; apply a sigmoid for
    the foreground probability. :meth:`select_inputs` turns the pipeline's motion images into that input,
    saturating the ED channel as ``ed_encoding`` says (``clip``, the paper's, or ``log``) and centring the flow
    channels as ``flow_centring`` says (``none``, the paper's; ``rigid``: :func:`centre_flow`; ``affine``:
    :func:`affine_flow_residual`). With ``flow_spread`` > 0 the input gets one more channel, last:
    :func:`flow_spread` over that many pixels square (of the flow before any centring).
    """

    def __init__(self, *, inputs: str = "ed+flow", depth: int = 4, widths: tuple[int, ...] = (16, 32, 64, 128),
                 head_channels: int = 128, ed_encoding: str = "clip", flow_centring: str = "none",
                 flow_spread: int = 0):
        super().__init__()
        if inputs not in INPUT_CHANNELS:
            raise ValueError(f"inputs: expected one of {', '.join(INPUT_CHANNELS)}, got {inputs!r}")
        if ed_encoding not in ED_ENCODINGS:
            raise ValueError(f"ed_encoding: expected one of {', '.join(ED_ENCODINGS)}, got {ed_encoding!r}")
        if flow_centring not in FLOW_CENTRINGS:
            raise ValueError(f"flow_centring: expected one of {', '.join(FLOW_CENTRINGS)}, got {flow_centring!r}")
        if flow_spread_problem(flow_spread):
            raise ValueError(f"flow_spread: {flow_spread_problem(flow_spread)}")
        if len(widths) < depth:
            raise ValueError(f"widths: need at least {depth} values for depth {depth}, got {list(widths)}")
        widths = tuple(int(w) for w in widths[:depth])
        self.config = {"inputs": inputs, "depth": depth, "widths": list(widths), "head_channels": head_channels,
                       "ed_encoding": ed_encoding, "flow_centring": flow_centring, "flow_spread": int(flow_spread)}
        self.channels = INPUT_CHANNELS[inputs]
        self.ed_encoding = ed_encoding
        self.flow_centring = flow_centring
        self.flow_spread = int(flow_spread)
        cin = self.input_channels
        self.encoder = nn.ModuleList()
        for width in widths:
            self.encoder.append(_conv_bn_relu(cin, width))
            cin = width
        self.bottleneck = _conv_bn_relu(widths[-1], widths[-1])
        self.decoder = nn.ModuleList()
        cin = widths[-1]
        for width in reversed(widths):
            self.decoder.append(_conv_bn_relu(cin + width, width))
            cin = width
        self.head = _conv_bn_relu(widths[0], head_channels, kernel=1)
        self.classifier = nn.Conv2d(head_channels, 1, 1)
        self._init_weights()

    def _init_weights(self) -> None:
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, nonlinearity="relu")
                if module.bias is not None:
                    nn.init.zeros_(module.bias)
        nn.init.normal_(self.classifier.weight, std=0.01)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for block in self.encoder:
            x = block(x)
            skips.append(x)
            x = F.max_pool2d(x, 2, ceil_mode=True)
        x = self.bottleneck(x)
        for block, skip in zip(self.decoder, reversed(skips)):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1))
        return self.classifier(self.head(x))

    @property
    def input_channels(self) -> int:
        """Channels of the input :meth:`select_inputs` makes."""
        return len(self.channels) + (1 if self.flow_spread else 0)

    def select_inputs(self, motion_images: torch.Tensor) -> torch.Tensor:
        """The channels of full (dx, dy, ED) motion images ``(B, 3, H, W)`` that this network reads, the ED
        channel (scaled over a window of frames, unsaturated) saturated by ``ed_encoding``, the flow centred by
        ``flow_centring``, then the :func:`flow_spread` channel where ``flow_spread`` > 0. A new tensor."""
        spread = flow_spread(motion_images, self.flow_spread) if self.flow_spread else None
        if self.flow_centring != "none" and 0 in self.channels:
            motion_images = _CENTRING[self.flow_centring](motion_images)
        x = motion_images[:, list(self.channels)]
        if 2 in self.channels:
            ed = self.channels.index(2)
            x[:, ed] = encode_ed(x[:, ed], self.ed_encoding)
        return x if spread is None else torch.cat([x, spread], dim=1)


def _folded(block: nn.Sequential) -> tuple[torch.Tensor, torch.Tensor]:
    """Weight ``(out, in, k, k)`` and bias ``(out,)`` of a conv + BatchNorm block with the BatchNorm's running
    statistics folded into the convolution (what the pair computes in eval mode)."""
    conv, norm = block[0], block[1]
    scale = norm.weight / torch.sqrt(norm.running_var + norm.eps)
    weight = conv.weight * scale[:, None, None, None]
    bias = norm.bias - norm.running_mean * scale
    if conv.bias is not None:
        bias = bias + conv.bias * scale
    return weight.detach().clone(), bias.detach().clone()


class InferenceUNet(nn.Module):
    """An :class:`EpoUNet` in eval mode, rebuilt for fast inference: every BatchNorm folded into its convolution,
    the ReLUs in place, each decoder convolution of the concatenation [upsampled, skip] as the sum of two
    convolutions (the concatenated copy at full resolution cost more than the convolution), the 1x1 head and
    classifier as matrix products over channels-last pixels (oneDNN would run them through its slow path). The same function of the input as ``model.eval()``, to float32 rounding
    (about 1e-5 on the logits); weights are copied, so later changes to ``model`` do not reach it.

    Input and output as :class:`EpoUNet` (``select_inputs`` included); channels-last input is fastest.
    """

    def __init__(self, model: EpoUNet):
        super().__init__()
        self.config, self.channels, self.ed_encoding = dict(model.config), model.channels, model.ed_encoding
        self.flow_centring, self.flow_spread = model.flow_centring, model.flow_spread
        frozen = lambda tensor: nn.Parameter(tensor.contiguous(), requires_grad=False)  # noqa: E731
        self.convs = nn.ParameterList()  # encoder blocks, then the bottleneck: weight, bias
        for block in [*model.encoder, model.bottleneck]:
            for tensor in _folded(block):
                self.convs.append(frozen(tensor))
        # decoder blocks: the convolution of the concatenation [upsampled, skip] as the sum of one convolution
        # of each part (no concatenated copy at full resolution): weight of the upsampled part, its bias, weight
        # of the skip's part
        self.decoder = nn.ParameterList()
        cin = model.config["widths"][-1]
        for block in model.decoder:
            weight, bias = _folded(block)
            self.decoder.extend([frozen(weight[:, :cin]), frozen(bias), frozen(weight[:, cin:])])
            cin = weight.shape[0]
        self.depth = len(model.encoder)
        head_weight, head_bias = _folded(model.head)
        self.head_weight = nn.Parameter(head_weight[:, :, 0, 0], requires_grad=False)
        self.head_bias = nn.Parameter(head_bias, requires_grad=False)
        self.classifier_weight = nn.Parameter(model.classifier.weight.detach()[:, :, 0, 0].clone(), requires_grad=False)
        self.classifier_bias = nn.Parameter(model.classifier.bias.detach().clone(), requires_grad=False)

    def _conv(self, index: int, x: torch.Tensor) -> torch.Tensor:
        weight, bias = self.convs[2 * index], self.convs[2 * index + 1]
        return F.relu_(F.conv2d(x, weight, bias, padding=weight.shape[-1] // 2))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i in range(self.depth):
            x = self._conv(i, x)
            skips.append(x)
            x = F.max_pool2d(x, 2, ceil_mode=True)
        x = self._conv(self.depth, x)
        for i, skip in enumerate(reversed(skips)):
            up_weight, bias, skip_weight = self.decoder[3 * i : 3 * i + 3]
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            pad = up_weight.shape[-1] // 2
            x = F.conv2d(x, up_weight, bias, padding=pad).add_(F.conv2d(skip, skip_weight, padding=pad))
            x = F.relu_(x)
        return self._head(x)

    def _head(self, x: torch.Tensor) -> torch.Tensor:
        """The 1x1 head and classifier over blocks of :data:`HEAD_BLOCK` pixels: the hidden layer of a whole
        batch at full resolution (B x H x W x ``head_channels`` floats, 210 MB for 16 frames of 427x240) went
        through memory twice, while a block's stays in the cache."""
        batch, channels, height, width = x.shape
        pixels = x.permute(0, 2, 3, 1).reshape(-1, channels)  # (B H W, C): a view of a channels-last tensor
        blocks = []
        for start in range(0, pixels.shape[0], HEAD_BLOCK):  # (F.linear, not addmm into one output: autocast)
            hidden = F.relu_(F.linear(pixels[start: start + HEAD_BLOCK], self.head_weight, self.head_bias))
            blocks.append(F.linear(hidden, self.classifier_weight, self.classifier_bias))
        return torch.cat(blocks).reshape(batch, height, width, -1).permute(0, 3, 1, 2)

    select_inputs = EpoUNet.select_inputs
    input_channels = EpoUNet.input_channels
