"""A compute-shader bitonic sort of Gaussians by depth (GL 4.3), measured against the numpy sort.

Kept for ``splatstyler bench viewer`` to compare on each machine; the renderer sorts with numpy (renderer_gl/
sort.py) because on this project's software-GL machines the numpy sort is far faster (docs/renderer.md). Its
result stays on the GPU: ``order`` is a buffer that can serve directly as the instance index buffer.
"""

from __future__ import annotations

import numpy as np

import moderngl

_KEYS = """
#version 430
layout(local_size_x = 256) in;
layout(std430, binding = 0) readonly buffer Means { vec4 means[]; };
layout(std430, binding = 1) buffer Keys { float keys[]; };
layout(std430, binding = 2) buffer Order { uint order[]; };
uniform vec3 u_forward;
uniform uint u_n;
void main() {
    uint i = gl_GlobalInvocationID.x;
    // Back to front: the farthest (largest depth) first, so sort ascending on -depth; padding sorts last.
    keys[i] = i < u_n ? -dot(u_forward, means[i].xyz) : 3.0e38;
    order[i] = i;
}
"""

_STEP = """
#version 430
layout(local_size_x = 256) in;
layout(std430, binding = 1) buffer Keys { float keys[]; };
layout(std430, binding = 2) buffer Order { uint order[]; };
uniform uint u_j;
uniform uint u_k;
void main() {
    uint i = gl_GlobalInvocationID.x;
    uint l = i ^ u_j;
    if (l > i) {
        bool ascending = (i & u_k) == 0u;
        float a = keys[i], b = keys[l];
        if ((a > b) == ascending) {
            keys[i] = b; keys[l] = a;
            uint t = order[i]; order[i] = order[l]; order[l] = t;
        }
    }
}
"""


class BitonicDepthSort:
    def __init__(self, ctx: moderngl.Context, means: np.ndarray):
        self.ctx = ctx
        self.n = len(means)
        self.size = max(256, 1 << int(np.ceil(np.log2(max(self.n, 1)))))
        padded = np.zeros((self.size, 4), np.float32)
        padded[: self.n, :3] = means
        self.means = ctx.buffer(padded.tobytes())
        self.keys = ctx.buffer(reserve=self.size * 4)
        self.order = ctx.buffer(reserve=self.size * 4)
        self._keys_prog = ctx.compute_shader(_KEYS)
        self._step_prog = ctx.compute_shader(_STEP)

    def sort(self, forward) -> None:
        self.means.bind_to_storage_buffer(0)
        self.keys.bind_to_storage_buffer(1)
        self.order.bind_to_storage_buffer(2)
        self._keys_prog["u_forward"].value = tuple(float(x) for x in forward)
        self._keys_prog["u_n"].value = self.n
        groups = self.size // 256
        self._keys_prog.run(groups)
        k = 2
        while k <= self.size:
            j = k // 2
            while j > 0:
                self.ctx.memory_barrier(moderngl.SHADER_STORAGE_BARRIER_BIT)
                self._step_prog["u_j"].value = j
                self._step_prog["u_k"].value = k
                self._step_prog.run(groups)
                j //= 2
            k *= 2
        self.ctx.memory_barrier()

    def read(self) -> np.ndarray:
        return np.frombuffer(self.order.read(), dtype=np.uint32)[: self.n].copy()

    def release(self) -> None:
        for obj in (self.means, self.keys, self.order, self._keys_prog, self._step_prog):
            obj.release()
