"""What the re-implemented published networks share: the sequence interface of the project's
networks (`model(spikes (B, K, T, H, W)) -> (B, K, H, W)` on the y scale), padding, the
representation front ends of model/published_reps.py, and a few blocks (Haar wavelets, plain
residual blocks).

Two kinds of network, told apart by `recurrent` (model/streaming.py runs both exactly, chunk by
chunk):
  * per-window (`recurrent = False`): `frames(spikes (N, T, H, W)) -> (N, H, W)`, each window on
    its own (Spk2ImgNet, WGSE, SSML);
  * forward-recurrent (`recurrent = True`): `step(spikes (B, T, H, W), state) ->
    (frame (B, H, W), state)`, state None before the first window (RSIR).
Inputs are padded (replicate) to multiples of `cfg.pad_multiple` and outputs cut back. A front
end's map is computed from each padded window alone, so one-shot and chunked inference see the
same maps and no spike times are carried between windows.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..blocks import pad_to_multiple, padded_size
from ..config import ModelConfig

#: ModelConfig's default representation, taken as "the net's own" (configs name it explicitly).
DEFAULT_REPRESENTATION = ModelConfig().representation
from ..published_reps import PUBLISHED_REPS, published_input_map


def front_end(name: str, window: int, channels: int) -> nn.Module:
    """The published representation `name` (model/published_reps.py) as an nn.Module mapping
    spikes (N, window, H, W) and its map (N, 1, H, W) or None to (N, channels, H, W)."""
    return PUBLISHED_REPS[name](window, channels)


def input_maps(name: str, spikes: torch.Tensor) -> torch.Tensor | None:
    """The one-channel map representation `name` takes, for each window on its own:
    spikes (..., K, T, H, W) -> (..., K, H, W) float32, or None."""
    lead, tail = spikes.shape[:-3], spikes.shape[-3:]
    m = published_input_map(name, spikes.reshape((-1, 1) + tuple(tail)))
    return None if m is None else m.reshape(tuple(lead) + tuple(tail[-2:])).to(torch.float32)


class PublishedNet(nn.Module):
    """Base of the re-implemented Table-1 networks: checks, padding, and the sequence loop."""

    recurrent = False
    representation = ""  # a key of model.published_reps.PUBLISHED_REPS

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        if cfg.representation not in (DEFAULT_REPRESENTATION, self.representation):
            raise ValueError(f"model.arch {cfg.arch!r} has its own front end, representation {self.representation!r}; "
                             f"model.representation={cfg.representation!r} would be ignored: set it to "
                             f"{self.representation!r} or leave it out")
        self.cfg = cfg

    def rep_maps(self, spikes: torch.Tensor, name: str | None = None) -> torch.Tensor | None:
        """The front end's map of each of N windows: (N, T, H, W) -> (N, 1, H, W) or None."""
        m = input_maps(name or self.representation, spikes.unsqueeze(1))
        return None if m is None else m.reshape(spikes.shape[0], 1, *spikes.shape[-2:])

    def padded_size(self, h: int, w: int) -> tuple[int, int]:
        return padded_size(h, w, self.cfg.pad_multiple)

    def pad(self, x: torch.Tensor) -> torch.Tensor:
        """Replicate-pad the last two dims up to multiples of pad_multiple."""
        return pad_to_multiple(x, self.cfg.pad_multiple)

    def check_input(self, spikes: torch.Tensor) -> None:
        if spikes.dim() != 5:
            raise ValueError(f"spikes must be (B, K, T, H, W), got shape {tuple(spikes.shape)}")
        if spikes.shape[2] != self.cfg.window:
            raise ValueError(f"windows have {spikes.shape[2]} steps but the model was built for "
                             f"window={self.cfg.window}")

    # ---- per-window / per-step pieces (subclasses) ------------------------------------------
    def frames(self, spikes: torch.Tensor) -> torch.Tensor:
        """Padded windows (N, T, H, W) float32 -> (N, H, W), each window on its own."""
        raise NotImplementedError

    def step(self, spikes: torch.Tensor, state: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """One window of a forward recurrence: padded (B, T, H, W) -> ((B, H, W), new state)."""
        raise NotImplementedError

    # ---- whole sequence ---------------------------------------------------------------------
    def forward(self, spikes: torch.Tensor) -> torch.Tensor:
        """spikes (B, K, T, H, W) bool/uint8/float 0-1 -> reconstructions (B, K, H, W), y scale."""
        self.check_input(spikes)
        b, k, t, h, w = spikes.shape
        x = self.pad(spikes.to(torch.float32))
        ph, pw = x.shape[-2:]
        if not self.recurrent:
            return self.frames(x.reshape(b * k, t, ph, pw)).reshape(b, k, ph, pw)[..., :h, :w]
        out, state = [], None
        for i in range(k):
            y, state = self.step(x[:, i], state)
            out.append(y)
        return torch.stack(out, 1)[..., :h, :w]


# ---- blocks ---------------------------------------------------------------------------------
def haar_dwt(x: torch.Tensor) -> torch.Tensor:
    """One level of the orthonormal 2-D Haar transform: (N, C, H, W), H and W even ->
    (N, 4C, H/2, W/2) as [LL, LH, HL, HH] channel blocks."""
    a, b = x[..., 0::2, 0::2], x[..., 0::2, 1::2]
    c, d = x[..., 1::2, 0::2], x[..., 1::2, 1::2]
    return 0.5 * torch.cat([a + b + c + d, a + b - c - d, a - b + c - d, a - b - c + d], 1)


def haar_idwt(y: torch.Tensor) -> torch.Tensor:
    """The inverse of haar_dwt: (N, 4C, H/2, W/2) -> (N, C, H, W)."""
    ll, lh, hl, hh = y.chunk(4, 1)
    top = torch.stack([ll + lh + hl + hh, ll + lh - hl - hh], -1).flatten(-2)     # row 2i: even, odd columns
    bottom = torch.stack([ll - lh + hl - hh, ll - lh - hl + hh], -1).flatten(-2)  # row 2i + 1
    return 0.5 * torch.stack([top, bottom], -2).flatten(-3, -2)


class PlainResBlock(nn.Module):
    """relu(x + conv(relu(conv(x)))): the residual block of WGSE and of many restoration nets;
    `convs` = 3 gives Spk2ImgNet's three-conv block."""

    def __init__(self, channels: int, convs: int = 2) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        for i in range(convs):
            layers.append(nn.Conv2d(channels, channels, 3, padding=1))
            if i < convs - 1:
                layers.append(nn.ReLU())
        self.body = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.body(x))


def res_stack(channels: int, blocks: int, convs: int = 2) -> nn.Sequential:
    return nn.Sequential(*(PlainResBlock(channels, convs) for _ in range(blocks)))
