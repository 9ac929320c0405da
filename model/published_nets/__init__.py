"""Learned methods of the LR-Rep paper's Table 1, re-implemented as architectures of this project
(ARCH_REGISTRY): `spk2imgnet` (Spk2ImgNet, CVPR 2021), `wgse` (WGSE, AAAI 2023), `rsir` (RSIR,
ACM MM 2023) and `ssml` (SSML, IJCAI 2022, self-supervised). Each module's docstring names its
source and where it departs from it. Importing this package registers them; `import model` does.
"""
from __future__ import annotations

from . import rsir, spk2imgnet, ssml, wgse
from .common import PublishedNet

__all__ = ["PublishedNet", "rsir", "spk2imgnet", "ssml", "wgse"]
