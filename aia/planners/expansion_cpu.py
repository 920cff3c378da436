"""The children of tree nodes (:meth:`aia.planners.tree.Expansion.extend`) as one compiled CPU kernel (numba).

In tensor ops an expansion is some 90 small operations (the arcs, the collision and sight checks, the
prediction with its det cap, the Kalman update of the visible targets, the log dets), and on the CPU their
dispatch is most of a call: on small3 at one world, 5,000 nodes per plan, the expansions took 40 of a call's
67 ms (49 expansions, 2026-12-02). This kernel does one parent's children in one loop, with the same
operations in the same order; ``benchmarks/arvi.py`` gives the figures.

Arithmetic: the arcs' cosines and sines come from torch (the caller passes them), so the child poses, the
collision checks and the children kept are bit for bit those of the tensor ops; the products and sums of the
filter are the tensor ops' own (sequential, as ATen's small batched products do: bit for bit). Square roots,
arc tangents, logarithms and the Cholesky factor of the log det are libm's and a plain Cholesky loop, which
differ from torch's vectorised ones and MKL's by an ulp or so: costs agree to about 1e-12 relative, and the
plans are the tensor ops' (``tests/planners/test_expansion_cpu.py``, ``tests/planners/test_plans.py``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from aia.envs.cpu_map_queries import fine_cell_near_occupied


def expand(parents: np.ndarray, pose: np.ndarray, cov: np.ndarray, logdet: np.ndarray, cost: np.ndarray,
           world: np.ndarray, world_maps: np.ndarray, positions: np.ndarray, arc_cos: np.ndarray,
           arc_sin: np.ndarray, out: dict[str, np.ndarray], chord: np.ndarray, turn: np.ndarray,
           collision: np.ndarray, fine_cell: float, supersample: int, margin: float, size: tuple[float, float],
           occupancy: np.ndarray, obstacles: bool, resolution: float, sight_fraction: np.ndarray,
           sensor_range: float, half_fov: float, min_range: float, transition: np.ndarray,
           process_noise: np.ndarray, meas_noise: np.ndarray, log_det_cap: float) -> int:
    """Write the collision-free children of ``parents`` (indices into the level's ``pose [n, 3]``, ``cov [n, N,
    4, 4]``, ``logdet [n, N]``, ``cost [n]``, ``world [n]``), parent by parent and action by action, to the
    first rows of ``out`` (an array per field of :class:`~aia.planners.tree.Level` but ``expanded``, a row per
    parent and action: the rows a :meth:`~aia.planners.tree.Level.reserve` gives); returns how many.

    ``arc_cos`` and ``arc_sin`` ``[P, A, K]`` are the cosines and sines of each parent's heading plus each
    primitive's half turn at the ``K`` checked points, ``chord`` and ``turn`` ``[A, K]`` the primitives'
    chords and turns; ``positions [W, N, 2]`` the targets' predicted positions at the children's depth.
    ``occupancy [M, ny, nx]`` holds the maps, world ``w`` planning on ``occupancy[world_maps[w]]``; it is read for
    lines of sight only where ``obstacles``. A point collides by the fine ``collision`` grid of the one map
    (``M = 1``), or, where that grid is empty (a map per world), by the margin test of
    :func:`aia.envs.sensing._near_occupied` on the world's map: the same float64 arithmetic, the same answers.
    """
    return _expand(parents, pose, cov, logdet, cost, world, world_maps, positions, arc_cos, arc_sin, chord, turn,
                   collision, fine_cell, supersample, margin, size[0], size[1], occupancy, obstacles, resolution,
                   sight_fraction, sensor_range, half_fov, min_range, transition, process_noise, meas_noise,
                   log_det_cap, out["pose"], out["cov"], out["logdet"], out["cost"], out["world"], out["parent"],
                   out["action"])


@numba.njit(cache=True, nogil=True)
def _cell(value: float, cell: float, cells: int) -> int:  # pragma: no cover - compiled
    """The clamped index of the cell holding ``value`` (``MapGeometry._cell_index`` for one coordinate)."""
    index = int(math.floor(value / cell))
    return min(max(index, 0), cells - 1)


@numba.njit(cache=True, nogil=True)
def _wrap(angle: float) -> float:  # pragma: no cover - compiled
    """``wrap_angle``: ``torch.remainder(angle + pi, 2 pi) - pi`` (fmod, moved to the divisor's sign)."""
    period = 2.0 * math.pi
    mod = np.fmod(angle + math.pi, period)
    if mod != 0 and (mod < 0) != (period < 0):
        mod += period
    return mod - math.pi


@numba.njit(cache=True, nogil=True)
def _near_occupied(occupancy: np.ndarray, x: float, y: float, resolution: float, supersample: int,
                   margin: float) -> bool:  # pragma: no cover - compiled
    """:func:`aia.envs.sensing._near_occupied` for the point ``(x, y)`` on the map ``occupancy [ny, nx]``: whether
    the centre of its fine cell lies within ``margin`` of the bounds or of an occupied cell's square."""
    ny, nx = occupancy.shape
    fine = resolution / supersample
    return fine_cell_near_occupied(occupancy, _cell(y, fine, ny * supersample), _cell(x, fine, nx * supersample),
                                   resolution, supersample, margin, 0)


@numba.njit(cache=True, nogil=True)
def _matmul(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out = a @ b``, each entry summed in order from 0 (ATen's small batched product)."""
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            acc = 0.0
            for k in range(a.shape[1]):
                acc += a[i, k] * b[k, j]
            out[i, j] = acc


@numba.njit(cache=True, nogil=True)
def _logdet(a: np.ndarray, factor: np.ndarray) -> float:  # pragma: no cover - compiled
    """Log determinant of the symmetric positive definite ``a [4, 4]`` by its Cholesky factor (NaN if not)."""
    size = a.shape[0]
    total = 0.0
    for j in range(size):
        s = a[j, j]
        for k in range(j):
            s -= factor[j, k] * factor[j, k]
        if not s > 0:
            return math.nan
        factor[j, j] = math.sqrt(s)
        for i in range(j + 1, size):
            s = a[i, j]
            for k in range(j):
                s -= factor[i, k] * factor[j, k]
            factor[i, j] = s / factor[j, j]
        total += math.log(factor[j, j])
    return 2.0 * total


@numba.njit(cache=True, nogil=True)
def _update(cov: np.ndarray, jacobian: np.ndarray, meas_noise: np.ndarray, out: np.ndarray,
            scratch: np.ndarray) -> None:  # pragma: no cover - compiled
    """``aia.planners.model.update_cov``: the Joseph-form Kalman covariance update, symmetrised (``scratch``:
    ``[7, 4, 4]`` work space)."""
    cov_ht, innovation, inverse, gain = scratch[0, :, :2], scratch[1, :2, :2], scratch[2, :2, :2], scratch[3, :, :2]
    reduce, joseph, noise = scratch[4], scratch[5], scratch[6]
    _matmul(cov, jacobian.T, cov_ht)
    _matmul(jacobian, cov_ht, innovation)
    for i in range(2):
        for j in range(2):
            innovation[i, j] += meas_noise[i, j]
    a, b, c, d = innovation[0, 0], innovation[0, 1], innovation[1, 0], innovation[1, 1]
    det = a * d - b * c
    inverse[0, 0], inverse[0, 1], inverse[1, 0], inverse[1, 1] = d / det, -b / det, -c / det, a / det
    _matmul(cov_ht, inverse, gain)
    _matmul(gain, jacobian, reduce)
    for i in range(4):
        for j in range(4):
            reduce[i, j] = (1.0 if i == j else 0.0) - reduce[i, j]
    _matmul(reduce, cov, noise)  # (I - K H) S, then its product with (I - K H)^T
    _matmul(noise, reduce.T, joseph)
    _matmul(gain, meas_noise, cov_ht)  # K V (K H's factors are used up), then K V K^T
    _matmul(cov_ht, gain.T, noise)
    for i in range(4):
        for j in range(4):
            joseph[i, j] += noise[i, j]
    for i in range(4):
        for j in range(4):
            out[i, j] = 0.5 * (joseph[i, j] + joseph[j, i])


@numba.njit(cache=True, nogil=True)
def _seen(x: float, y: float, heading: float, dx: float, dy: float, distance: float, occupancy: np.ndarray,
          obstacles: bool, resolution: float, sight_fraction: np.ndarray, sensor_range: float, half_fov: float,
          min_range: float) -> bool:  # pragma: no cover - compiled
    """``visible_targets`` of the target at ``(dx, dy)`` and ``distance`` from ``(x, y)``: in range (and at least
    ``min_range`` away), in the field of view, in sight."""
    bearing = _wrap(math.atan2(dy, dx) - heading)
    if not (distance <= sensor_range and abs(bearing) <= half_fov):
        return False
    if min_range > 0 and not distance >= min_range:
        return False
    if obstacles:
        rows, columns = occupancy.shape
        for s in range(sight_fraction.shape[0]):
            px = x + dx * sight_fraction[s]
            py = y + dy * sight_fraction[s]
            if occupancy[_cell(py, resolution, rows), _cell(px, resolution, columns)]:
                return False
    return True


@numba.njit(cache=True, nogil=True)
def _expand(parents, pose, cov, logdet, cost, world, world_maps, positions, arc_cos, arc_sin, chord, turn, collision,
            fine_cell, supersample, margin, size_x, size_y, occupancy, obstacles, resolution, sight_fraction,
            sensor_range, half_fov, min_range, transition, process_noise, meas_noise, log_det_cap, out_pose, out_cov,
            out_logdet, out_cost, out_world, out_parent, out_action) -> int:  # pragma: no cover - compiled
    num_actions, checks = chord.shape
    targets = cov.shape[1]
    rows, columns = collision.shape
    grid = rows > 0  # the one map's collision grid; else each world's margin test
    capped = log_det_cap < math.inf
    predicted = np.empty((targets, 4, 4))
    predicted_logdet = np.empty(targets)
    product = np.empty((4, 4))
    factor = np.zeros((4, 4))
    jacobian = np.zeros((2, 4))
    scratch = np.empty((7, 4, 4))
    made = 0
    for local in range(parents.shape[0]):
        node = parents[local]
        px, py, heading = pose[node, 0], pose[node, 1], pose[node, 2]
        # the prediction A S A^T + W of each target, kept at the prior where it reaches the det cap
        for n in range(targets):
            _matmul(transition, cov[node, n], product)
            _matmul(product, transition.T, predicted[n])
            for i in range(4):
                for j in range(4):
                    predicted[n, i, j] += process_noise[i, j]
            predicted_logdet[n] = _logdet(predicted[n], factor)
            if capped and predicted_logdet[n] >= log_det_cap:
                predicted[n] = cov[node, n]
                predicted_logdet[n] = logdet[node, n]
        w = world[node]
        world_map = occupancy[world_maps[w]]
        for action in range(num_actions):
            free = True
            x = y = 0.0
            for k in range(checks):
                x = px + chord[action, k] * arc_cos[local, action, k]
                y = py + chord[action, k] * arc_sin[local, action, k]
                if x < 0 or y < 0 or x > size_x or y > size_y:
                    free = False
                elif grid:
                    free = not collision[_cell(y, fine_cell, rows), _cell(x, fine_cell, columns)]
                else:
                    free = not _near_occupied(world_map, x, y, resolution, supersample, margin)
                if not free:
                    break
            if not free:
                continue
            theta = _wrap(heading + turn[action, checks - 1])
            out_pose[made, 0], out_pose[made, 1], out_pose[made, 2] = x, y, theta
            total = 0.0
            for n in range(targets):
                dx, dy = positions[w, n, 0] - x, positions[w, n, 1] - y
                r2 = dx * dx + dy * dy  # range_bearing's and measurement_jacobian's, computed once
                r = math.sqrt(r2)
                if _seen(x, y, theta, dx, dy, r, world_map, obstacles, resolution, sight_fraction, sensor_range,
                         half_fov, min_range):
                    jacobian[0, 0], jacobian[0, 1] = dx / r, dy / r
                    jacobian[1, 0], jacobian[1, 1] = -dy / r2, dx / r2
                    _update(predicted[n], jacobian, meas_noise, out_cov[made, n], scratch)
                    out_logdet[made, n] = _logdet(out_cov[made, n], factor)
                else:
                    out_cov[made, n] = predicted[n]
                    out_logdet[made, n] = predicted_logdet[n]
                total += out_logdet[made, n]
            out_cost[made] = cost[node] + total
            out_world[made], out_parent[made], out_action[made] = w, node, action
            made += 1
    return made
