"""Random shapes, dtypes, strides and values into ``reconstruct``, ``integrate`` and
``angular_error``: whatever comes in, the answer is a result or a PhotostereoError, never
another exception, a crash of the interpreter or a hang."""

import time

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import photostereo as ps

DTYPES = [
    np.uint8,
    np.uint16,
    np.int16,
    np.int64,
    np.float16,
    np.float32,
    np.float64,
    np.complex64,
    np.bool_,
]
SETTINGS = dict(
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
#: No single call may take longer: a hang fails the test instead of stalling it.
MAX_SECONDS = 20.0


@st.composite
def views(draw, shapes, dtypes=st.sampled_from(DTYPES)):
    """An array of a random dtype and shape, seen through random strides: reversed or stepped
    axes, a transposition, or a broadcast (zero strides)."""
    dtype = draw(dtypes)
    shape = draw(shapes)
    a = draw(hnp.arrays(dtype, shape))
    how = draw(st.sampled_from(["plain", "reversed", "stepped", "transposed", "broadcast"]))
    if how == "reversed" and a.ndim:
        a = a[tuple(slice(None, None, -1) for _ in range(a.ndim))]
    elif how == "stepped" and a.ndim:
        a = np.repeat(a, 2, axis=0)[::2]
    elif how == "transposed" and a.ndim > 1:
        a = np.swapaxes(np.ascontiguousarray(np.swapaxes(a, 0, -1)), 0, -1)
    elif how == "broadcast" and a.ndim and a.size:
        a = np.broadcast_to(a[(slice(0, 1),) * a.ndim], a.shape)
    return a


def dims(min_dims, max_dims, max_side=8):
    return hnp.array_shapes(min_dims=min_dims, max_dims=max_dims, min_side=0, max_side=max_side)


#: Mostly ordinary values, now and then NaN, infinities or huge ones.
REALS = st.floats(0, 1) | st.floats(-1e3, 1e3) | st.sampled_from([np.nan, np.inf, -np.inf, 1e300])


@st.composite
def stacks(draw):
    """Image stacks close to what a user gives: 3 to 8 images of up to 10 × 10 pixels, grey or
    RGB, of an accepted dtype, in random strides."""
    n, h, w = draw(st.integers(3, 8)), draw(st.integers(1, 10)), draw(st.integers(1, 10))
    shape = draw(st.sampled_from([(n, h, w), (n, h, w, 1), (n, h, w, 3)]))
    dtype = draw(st.sampled_from([np.uint8, np.uint16, np.float32, np.float64]))
    floats = np.issubdtype(dtype, np.floating)
    elements = (REALS if draw(st.booleans()) else st.floats(0, 1)) if floats else None
    base = draw(hnp.arrays(dtype, shape, elements=elements))
    return restride(base, draw(st.sampled_from(["plain", "reversed", "stepped", "transposed"])))


def restride(a, how):
    if how == "reversed":
        return a[::-1, :, ::-1]
    if how == "stepped":
        return np.repeat(a, 2, axis=1)[:, ::2]
    if how == "transposed":
        return np.swapaxes(np.ascontiguousarray(np.swapaxes(a, 1, 2)), 1, 2)
    return a


@st.composite
def directions(draw, n):
    """n light directions spread over the camera's side (a seeded draw, so that they are not
    all alike), now and then a bad one."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    a = np.column_stack([rng.uniform(-0.9, 0.9, (n, 2)), rng.uniform(0.2, 1.0, n)])
    if n and draw(st.integers(0, 9)) == 0:
        a[draw(st.integers(0, n - 1)), draw(st.integers(0, 2))] = draw(REALS)
    return a


def lights_like(n):
    return directions(n) | hnp.arrays(
        np.float64,
        st.sampled_from([(n, 3), (n, 2), (max(n - 1, 0), 3), (n,)]),
        elements=st.floats(-2, 2) | st.just(np.nan),
    )


@st.composite
def normal_maps(draw, h=None, w=None):
    """(H, W, 3) normal maps of up to 12 × 12 pixels, mostly facing the camera."""
    h = draw(st.integers(0, 12)) if h is None else h
    w = draw(st.integers(0, 12)) if w is None else w
    xy = st.floats(-1, 1)
    z = st.floats(-0.2, 1) | REALS
    a = np.array([[draw(xy), draw(xy), draw(z)] for _ in range(h * w)], dtype=np.float64)
    with np.errstate(over="ignore"):
        return a.astype(np.float32).reshape(h, w, 3)


def call(f, *args, **kwargs):
    """Calls `f`: its result, or None when it raised PhotostereoError. Any other exception
    fails the test, as does a call that takes too long."""
    start = time.monotonic()
    try:
        return f(*args, **kwargs)
    except ps.PhotostereoError:
        return None
    finally:
        assert time.monotonic() - start < MAX_SECONDS, (f.__name__, kwargs)


@settings(max_examples=1200, **SETTINGS)
@given(
    images=stacks() | stacks() | views(dims(2, 5)),
    data=st.data(),
    method=st.sampled_from(["l2", "coleman-jain", "barsky-petrou", "recursive"]),
    num_threads=st.sampled_from([None, None, None, 1, 2, 0, -1, 10**12]),
    extra=st.dictionaries(
        st.sampled_from(["confidence", "max_slope", "relative_noise", "consensus_radius",
                         "memory_limit", "integrator", "surface_prior"]),
        st.none() | st.integers(-3, 10**15) | st.floats(allow_nan=True) | st.text(max_size=3),
        max_size=2,
    )
    | st.just({})
    | st.just({}),
)
def test_reconstruct_takes_anything(images, data, method, num_threads, extra):
    n = images.shape[0] if images.ndim else 0
    lights = data.draw(lights_like(n))
    mask = None
    choice = data.draw(st.integers(0, 3))
    if choice == 1 and images.ndim >= 3:
        mask = data.draw(hnp.arrays(np.bool_, images.shape[1:3]))
    elif choice == 2:
        mask = data.draw(views(dims(1, 3), st.sampled_from([np.bool_, np.uint8, np.float32])))
    rec = call(ps.reconstruct, images, lights, mask, method=method, num_threads=num_threads,
               **extra)
    if rec is not None:
        h, w = images.shape[1:3]
        assert rec.normals.shape == (h, w, 3) and rec.normals.dtype == np.float32
        assert rec.light_status.shape == (n, h, w)


@settings(max_examples=1000, **SETTINGS)
@given(
    normals=normal_maps() | normal_maps() | views(dims(0, 4)),
    data=st.data(),
    method=st.sampled_from(["poisson", "poisson", "dct", "fft", "paths", "magic"]),
    max_slope=st.just(20.0) | st.floats(allow_nan=True) | st.integers(-5, 5),
)
def test_integrate_takes_anything(normals, data, method, max_slope):
    shape = normals.shape[:2] if normals.ndim >= 2 else (0, 0)
    mask = data.draw(st.none() | views(st.sampled_from([shape, (1, 1), (3,)]), st.just(np.bool_)))
    weights = data.draw(st.none() | views(st.sampled_from([shape, (2, 2)]),
                                          st.sampled_from([np.float32, np.float64, np.int8])))
    depth = call(ps.integrate, normals, mask, method, weights, max_slope=max_slope)
    if depth is not None:
        assert depth.shape == normals.shape[:2] and depth.dtype == np.float32


@settings(max_examples=1000, **SETTINGS)
@given(normals=normal_maps() | views(dims(0, 4)), data=st.data())
def test_angular_error_takes_anything(normals, data):
    same = normal_maps(*normals.shape[:2]) if normals.ndim == 3 else st.nothing()
    truth = data.draw(same | same | views(st.sampled_from([normals.shape, (2, 2, 3), (1,)])))
    mask = data.draw(st.none() | views(st.sampled_from([normals.shape[:2], (1, 1)]),
                                       st.sampled_from([np.bool_, np.int32])))
    err = call(ps.angular_error, normals, truth, mask)
    if err is not None:
        assert err.map.shape == normals.shape[:2]
        assert 0 <= err.pixels <= normals.shape[0] * normals.shape[1]
