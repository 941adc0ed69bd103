"""OSNet (Zhou et al., "Omni-Scale Feature Learning for Person Re-Identification", ICCV 2019)
in torch, parameter-compatible with torchreid's ``osnet_*`` models.

The module and attribute names below are what make a torchreid checkpoint load: the state-dict
keys are the attribute paths (``conv2.0.conv2b.1.conv1.weight``, ``fc.1.running_mean``, ...).

Architecture, as torchreid builds it:

* stem: 7x7/2 conv + BN + ReLU, 3x3/2 max-pool;
* three stages (``conv2``, ``conv3``, ``conv4``) of two :class:`OSBlock` each; the first two stages
  end with a 1x1 conv + 2x2 average pool (a transition that halves the resolution);
* ``conv5``: 1x1 conv + BN + ReLU; global average pooling;
* ``fc``: Linear -> BatchNorm1d -> ReLU to ``feature_dim`` (512); in eval mode this is the
  re-id feature. ``classifier`` (Linear to the training identities) only serves training.

:class:`OSBlock` is the omni-scale residual bottleneck: a 1x1 reduction to ``out/4`` channels,
four streams of 1, 2, 3 and 4 stacked "lite 3x3" layers (1x1 linear conv, then a depthwise 3x3
conv, BN, ReLU), i.e. receptive fields 3, 5, 7 and 9, fused by the *unified aggregation gate*: one
:class:`ChannelGate` (global pool -> 1x1 conv -> ReLU -> 1x1 conv -> sigmoid, shared by the four
streams) weights each stream channel-wise and the results are summed; a 1x1 linear conv expands
back, plus the (projected when the width changes) identity, then ReLU.

Widths: ``x1_0`` = [64, 256, 384, 512], ``x0_75`` = [48, 192, 288, 384], ``x0_5`` = [32, 128,
192, 256], ``x0_25`` = [16, 64, 96, 128]; ``ibn_x1_0`` adds instance normalisation to the stem
and the first stage. ``feature_dim`` is 512 for every variant.

Torch is imported by this module: import it only when OSNet is configured.
"""
from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import torch
from torch import nn
from torch.nn import functional as F

from edge_node.perception import PerceptionError

FEATURE_DIM = 512
VARIANTS: dict[str, tuple[tuple[int, int, int, int], bool]] = {
    # name: (channels, instance norm in the stem and first stage)
    "x1_0": ((64, 256, 384, 512), False),
    "x0_75": ((48, 192, 288, 384), False),
    "x0_5": ((32, 128, 192, 256), False),
    "x0_25": ((16, 64, 96, 128), False),
    "ibn_x1_0": ((64, 256, 384, 512), True),
}


# -- layers -------------------------------------------------------------------------------------
class ConvLayer(nn.Module):
    """k x k convolution, batch norm (instance norm with ``IN``), ReLU."""

    def __init__(self, cin: int, cout: int, k: int, stride: int = 1, padding: int = 0,
                 IN: bool = False):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, k, stride=stride, padding=padding, bias=False)
        self.bn = nn.InstanceNorm2d(cout, affine=True) if IN else nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x):
        return self.relu(self.bn(self.conv(x)))


class Conv1x1(nn.Module):
    """1x1 convolution, batch norm, ReLU."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, 1, bias=False)
        self.bn = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x):
        return self.relu(self.bn(self.conv(x)))


class Conv1x1Linear(nn.Module):
    """1x1 convolution and batch norm, no non-linearity."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, 1, bias=False)
        self.bn = nn.BatchNorm2d(cout)

    def forward(self, x):
        return self.bn(self.conv(x))


class LightConv3x3(nn.Module):
    """The "lite 3x3": a 1x1 linear convolution, then a depthwise 3x3, batch norm, ReLU."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 1, bias=False)
        self.conv2 = nn.Conv2d(cout, cout, 3, padding=1, bias=False, groups=cout)
        self.bn = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x):
        return self.relu(self.bn(self.conv2(self.conv1(x))))


class ChannelGate(nn.Module):
    """The unified aggregation gate: channel weights in (0, 1) computed from the input itself
    (global average pool, bottleneck of ``channels // 16``, sigmoid), multiplied onto it."""

    def __init__(self, channels: int, reduction: int = 16):
        super().__init__()
        hidden = channels // reduction
        self.global_avgpool = nn.AdaptiveAvgPool2d(1)
        self.fc1 = nn.Conv2d(channels, hidden, 1, bias=True)
        self.relu = nn.ReLU(inplace=True)
        self.fc2 = nn.Conv2d(hidden, channels, 1, bias=True)
        self.gate_activation = nn.Sigmoid()

    def forward(self, x):
        g = self.gate_activation(self.fc2(self.relu(self.fc1(self.global_avgpool(x)))))
        return x * g


class OSBlock(nn.Module):
    """Omni-scale residual block: four lite-3x3 streams (depth 1..4) under one shared gate."""

    def __init__(self, cin: int, cout: int, IN: bool = False, bottleneck_reduction: int = 4):
        super().__init__()
        mid = cout // bottleneck_reduction
        self.conv1 = Conv1x1(cin, mid)
        self.conv2a = LightConv3x3(mid, mid)
        self.conv2b = nn.Sequential(*(LightConv3x3(mid, mid) for _ in range(2)))
        self.conv2c = nn.Sequential(*(LightConv3x3(mid, mid) for _ in range(3)))
        self.conv2d = nn.Sequential(*(LightConv3x3(mid, mid) for _ in range(4)))
        self.gate = ChannelGate(mid)
        self.conv3 = Conv1x1Linear(mid, cout)
        self.downsample = Conv1x1Linear(cin, cout) if cin != cout else None
        self.IN = nn.InstanceNorm2d(cout, affine=True) if IN else None

    def forward(self, x):
        x1 = self.conv1(x)
        streams = (self.conv2a(x1), self.conv2b(x1), self.conv2c(x1), self.conv2d(x1))
        fused = sum(self.gate(s) for s in streams)
        out = self.conv3(fused) + (x if self.downsample is None else self.downsample(x))
        if self.IN is not None:
            out = self.IN(out)
        return F.relu(out)


class OSNet(nn.Module):
    """The omni-scale network; ``forward`` in eval mode returns the ``feature_dim`` re-id
    feature (after ``fc``), in train mode the identity logits."""

    def __init__(self, channels=(64, 256, 384, 512), num_classes: int = 1000,
                 feature_dim: int = FEATURE_DIM, IN: bool = False, layers=(2, 2, 2)):
        super().__init__()
        c0, c1, c2, c3 = channels
        self.feature_dim = feature_dim
        self.conv1 = ConvLayer(3, c0, 7, stride=2, padding=3, IN=IN)
        self.maxpool = nn.MaxPool2d(3, stride=2, padding=1)
        self.conv2 = self._stage(layers[0], c0, c1, transition=True, IN=IN)
        self.conv3 = self._stage(layers[1], c1, c2, transition=True)
        self.conv4 = self._stage(layers[2], c2, c3, transition=False)
        self.conv5 = Conv1x1(c3, c3)
        self.global_avgpool = nn.AdaptiveAvgPool2d(1)
        self.fc = nn.Sequential(nn.Linear(c3, feature_dim), nn.BatchNorm1d(feature_dim),
                                nn.ReLU(inplace=True))
        self.classifier = nn.Linear(feature_dim, num_classes)
        self._init_params()

    @staticmethod
    def _stage(n: int, cin: int, cout: int, transition: bool, IN: bool = False) -> nn.Sequential:
        blocks: list[nn.Module] = [OSBlock(cin, cout, IN=IN)]
        blocks += [OSBlock(cout, cout, IN=IN) for _ in range(1, n)]
        if transition:
            blocks.append(nn.Sequential(Conv1x1(cout, cout), nn.AvgPool2d(2, stride=2)))
        return nn.Sequential(*blocks)

    def _init_params(self) -> None:
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, (nn.BatchNorm2d, nn.BatchNorm1d, nn.InstanceNorm2d)):
                if m.weight is not None:
                    nn.init.ones_(m.weight)
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.Linear):
                nn.init.normal_(m.weight, 0.0, 0.01)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)

    def featuremaps(self, x):
        x = self.maxpool(self.conv1(x))
        return self.conv5(self.conv4(self.conv3(self.conv2(x))))

    def forward(self, x):
        v = self.global_avgpool(self.featuremaps(x)).flatten(1)
        v = self.fc(v)
        return v if not self.training else self.classifier(v)


def osnet(variant: str = "x1_0", num_classes: int = 1000) -> OSNet:
    """An OSNet of ``variant`` (``x1_0``, ``x0_75``, ``x0_5``, ``x0_25``, ``ibn_x1_0``; an
    ``osnet_`` prefix is accepted) with random weights."""
    name = variant.removeprefix("osnet_")
    if name not in VARIANTS:
        raise PerceptionError(f"unknown OSNet variant {variant!r} "
                              f"(known: {', '.join('osnet_' + v for v in VARIANTS)})")
    channels, IN = VARIANTS[name]
    return OSNet(channels, num_classes=num_classes, IN=IN)


# -- torchreid checkpoints ------------------------------------------------------------------------
def _state_dict_of(obj, path: Path) -> dict:
    """The parameter dict inside a loaded checkpoint: torchreid saves ``{'state_dict': ...,
    'epoch': ..., ...}``; a bare state dict (or ``{'model': ...}``) works too."""
    if isinstance(obj, nn.Module):
        obj = obj.state_dict()
    if isinstance(obj, dict):
        for key in ("state_dict", "model", "net"):
            if key in obj and isinstance(obj[key], dict):
                return obj[key]
        if obj and all(isinstance(k, str) for k in obj) and any(
                torch.is_tensor(v) for v in obj.values()):
            return obj
    raise PerceptionError(f"{path}: not a torchreid checkpoint (expected a state_dict of "
                          f"tensors, or a dict with a 'state_dict' key; got {type(obj).__name__}"
                          + (f" with keys {sorted(obj)[:8]}" if isinstance(obj, dict) else "")
                          + ")")


def load_torchreid_checkpoint(model: nn.Module, path: str | Path) -> dict:
    """Load a torchreid-format checkpoint into ``model`` and return a small report.

    Accepts ``{'state_dict': {...}}`` or a bare state dict; strips ``module.`` prefixes
    (``nn.DataParallel``); ignores ``classifier.*`` (the training identities: any number of them).
    Every other parameter and buffer of the model must be present with the right shape, and no
    other key may be left over: anything else is a :class:`PerceptionError` that names the
    missing, unexpected and mis-shaped keys (a checkpoint of another architecture or width fails
    here, at start-up, not with silently random features).
    """
    path = Path(path)
    if not path.is_file():
        raise PerceptionError(f"OSNet weights file not found: {path}")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - pickle, zip and torch errors alike
        raise PerceptionError(f"{path}: cannot read the checkpoint ({type(e).__name__}: {e})"
                              ) from None
    raw = _state_dict_of(obj, path)
    state: OrderedDict[str, torch.Tensor] = OrderedDict()
    ignored = []
    for k, v in raw.items():
        while k.startswith("module."):
            k = k[len("module."):]
        if k.startswith("classifier."):
            ignored.append(k)
            continue
        state[k] = v
    own = {k: v for k, v in model.state_dict().items() if not k.startswith("classifier.")}
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shape = sorted(k for k in set(own) & set(state)
                   if not torch.is_tensor(state[k]) or tuple(state[k].shape) != tuple(own[k].shape))
    if missing or unexpected or shape:
        def few(keys):
            return ", ".join(keys[:5]) + (f" ... ({len(keys)} in all)" if len(keys) > 5 else "")
        parts = []
        if missing:
            parts.append(f"missing keys: {few(missing)}")
        if unexpected:
            parts.append(f"unexpected keys: {few(unexpected)}")
        if shape:
            parts.append("shape mismatch: " + few([f"{k} {tuple(state[k].shape)} vs "
                                                   f"{tuple(own[k].shape)}" for k in shape]))
        raise PerceptionError(f"{path}: does not fit this OSNet ({'; '.join(parts)}); is it the "
                              "right variant (x1_0 / x0_25 ...)?")
    merged = model.state_dict()
    merged.update(state)
    model.load_state_dict(merged)
    return {"loaded": len(state), "ignored": ignored}
