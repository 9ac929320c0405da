import numpy as np, sys
from spikesim.render import SceneRenderer
from spikesim.camera import SpikeCamera
cam = SpikeCamera.realistic(height=8, width=32)
a = SceneRenderer("scenes/fan/scene.xml", light="normal", variant="mono", spp=4, camera=cam)
b = SceneRenderer("scenes/fan/scene.xml", light="normal", variant="mono", spp=4, camera=cam)
b.freeze_renders = False
for s in [0, 430, 431, 400, 404, 408, 412, 0, 408]:
    fa = a._film(s, 4, 0); fb = b._film(s, 4, 0)
    print(s, a.substeps_for(s), "nan frozen", int(np.isnan(fa).sum()), "nan traced", int(np.isnan(fb).sum()), "equal", np.array_equal(fa, fb, equal_nan=True), a._frozen_render.n_recordings)
