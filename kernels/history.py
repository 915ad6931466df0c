"""BDF-alpha bookkeeping of dynamics on the device, in one launch per step: the history of
every slot, the tip kinematics, and the Newton start of the next step.

BDF-alpha [T19]: y_t = c0 y + y_h, y_h = c1 y(i) + c2 y(i-1) + d1 y_t(i).
"""

import functools
from types import SimpleNamespace

import warp as wp


@functools.cache
def make_history_kernels(dtype, nu: int = 6):
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    vecx = wp.types.vector(nu, dtype)
    module = f"tdcr_warp_history_{wp.types.type_repr(dtype)}_{nu}"

    @wp.kernel(module=module, enable_backward=False)
    def end_step(
        ycur: wp.array3d(dtype=vec3),
        yprev: wp.array3d(dtype=vec3),
        hist: wp.array3d(dtype=vec3),
        p: wp.array2d(dtype=vec3),
        R: wp.array2d(dtype=mat33),
        q: wp.array2d(dtype=vec3),
        ok: wp.array(dtype=int),
        c0: wp.float64,
        c1: wp.float64,
        c2: wp.float64,
        d1: wp.float64,
        at_rest: int,
        tip_p: wp.array(dtype=wp.vec3d),
        tip_v: wp.array(dtype=wp.vec3d),
        tip_a: wp.array(dtype=wp.vec3d),
        vel_hist: wp.array(dtype=wp.vec3d),
        vel_prev: wp.array(dtype=wp.vec3d),
        x: wp.array(dtype=vecx),
        x_prev: wp.array(dtype=vecx),
        x_start: wp.array(dtype=vecx),
    ):
        """After a step, per rod whose step converged (``ok``):
        - the history of every slot and quantity: y_h <- c1 y(i) + c2 y(i-1) + d1 y_t(i) with
          y_t(i) = c0 y(i) + y_h, and y(i-1) <- y(i) (at_rest = 1, the start from equilibrium:
          y(i-1) = y(i) and y_t(i) = 0, so that the next step sees y_t = 0 at the same state);
        - the tip position, velocity R q and acceleration (BDF-alpha of the velocity), float64
          (not at rest: the static tip stands);
        and for every rod the Newton start of the next step, the extrapolation 2 x(i) - x(i-1)
        (the shooting residual amplifies a start error by up to ~1e4 at small dt; at rest:
        x(i)), with x(i-1) <- x(i)."""
        b = wp.tid()
        xi = x[b]
        if at_rest != 0:
            x_start[b] = xi
        else:
            x_start[b] = dtype(2.0) * xi - x_prev[b]
        x_prev[b] = xi
        if ok[b] == 0:
            return
        h0 = dtype(c0)
        h1 = dtype(c1)
        h2 = dtype(c2)
        h3 = dtype(d1)
        for sl in range(ycur.shape[1]):
            for c in range(ycur.shape[2]):
                y = ycur[b, sl, c]
                yt = h0 * y + hist[b, sl, c]
                yp = yprev[b, sl, c]
                if at_rest != 0:
                    yt = vec3()
                    yp = y
                hist[b, sl, c] = h1 * y + h2 * yp + h3 * yt
                yprev[b, sl, c] = y
        if at_rest != 0:
            return
        k = p.shape[1] - 1
        v = wp.vec3d(R[b, k] * q[b, k])
        acc = c0 * v + vel_hist[b]
        vel_hist[b] = c1 * v + c2 * vel_prev[b] + d1 * acc
        vel_prev[b] = v
        tip_p[b] = wp.vec3d(p[b, k])
        tip_v[b] = v
        tip_a[b] = acc

    return SimpleNamespace(end_step=end_step, module=module)
