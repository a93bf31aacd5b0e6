"""Writes tests/data/nerfstudio_capture: nerfstudio's own `colmap_to_json` (nerfstudio 1.1.5, from
PyPI) run on the largest model of tests/data/colmap_workspaces/opencv, as `ns-process-data` runs it
after COLMAP: transforms.json (OPENCV lens, OpenGL camera-to-world poses in nerfstudio's turned
world frame) and sparse_pc.ply (COLMAP's points in that frame).

nerfstudio imports torch, which this machine's registries serve only as a multi-gigabyte CUDA
build. `colmap_to_json` uses torch for one thing, turning the points by `applied_transform`
(`torch.from_numpy`, `.float()`, `torch.einsum`); a stand-in module does those three in numpy.
Every other line that writes the files is nerfstudio's. Two modules it imports and this function
does not use (colormaps, rawpy) are stubbed. Usage: scripts/data/make-nerfstudio-capture.sh
"""
import sys
import types
from pathlib import Path

import numpy as np

pkg, workspace, out = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
sys.path.insert(0, str(pkg))


class _Tensor(np.ndarray):
    def float(self):
        return np.asarray(self, dtype=np.float32).view(_Tensor)


torch = types.ModuleType("torch")
torch.Tensor = _Tensor
torch.from_numpy = lambda a: np.asarray(a).view(_Tensor)
torch.einsum = lambda spec, *ops: np.einsum(spec, *[np.asarray(o) for o in ops]).view(_Tensor)
sys.modules["torch"] = torch
sys.modules["nerfstudio.utils.colormaps"] = types.ModuleType("nerfstudio.utils.colormaps")
sys.modules["rawpy"] = types.ModuleType("rawpy")

from nerfstudio.data.utils.colmap_parsing_utils import read_images_binary  # noqa: E402
from nerfstudio.process_data import colmap_utils  # noqa: E402

models = sorted((workspace / "sparse").iterdir())
best = max(models, key=lambda d: len(read_images_binary(d / "images.bin")))
out.mkdir(parents=True, exist_ok=True)
n = colmap_utils.colmap_to_json(recon_dir=best, output_dir=out)
print(f"{out}: {n} frames from {best}")
