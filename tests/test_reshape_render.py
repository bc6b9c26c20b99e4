"""Depth order, textured-mesh rendering and the animation writers."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from nnsf.errors import InputError
from stick_figure import stick_figure
from nnsf.reshape.depth import (
    default_order, depth_metric, depth_orders, order_ranks, part_depths, part_overlaps,
)
from nnsf.reshape.animator import Animator
from nnsf.reshape.mesh import Mesh
from nnsf.reshape.parts import PARTS, PART_INDEX
from nnsf.reshape.render import Renderer
from nnsf.reshape.video import read_gif, write_gif, write_mp4, write_png_frames


@pytest.fixture(scope="module")
def figure():
    return stick_figure(height=240)


@pytest.fixture(scope="module")
def rig(figure):
    return Animator(figure, n_vertices=400)


def _renderer(uv, T, parts, tex, size=None, mask=None):
    """A renderer of a hand-made mesh: rest vertices ``uv`` (texture pixels), triangles ``T``."""
    mesh = Mesh(np.asarray(uv, float), np.asarray(T), np.asarray(parts), np.zeros(len(T), np.int64), 1.0)
    return Renderer(mesh, tex, np.ones(tex.shape[:2], bool) if mask is None else mask, size or tex.shape[:2])


# --------------------------------------------------------------------------- depth

def _two_parts(z_arm):
    """Part depths (T, 10): everything at 0 except the left forearm at ``z_arm`` (T,)."""
    z = np.zeros((len(z_arm), len(PARTS)))
    z[:, PART_INDEX["torso"]] = 0.0
    z[:, PART_INDEX["l_forearm"]] = z_arm
    return z


def test_order_follows_clear_depth_and_ignores_noise_within_the_band():
    T = 60
    base = np.where(np.arange(T) < 30, -5.0, 5.0)  # in front, then behind the torso
    noise = np.random.default_rng(0).uniform(-0.9, 0.9, T)
    z = _two_parts(base + noise)
    orders = depth_orders(z, hysteresis=1.0)
    r = order_ranks(orders)
    torso, arm = PART_INDEX["torso"], PART_INDEX["l_forearm"]
    in_front = r[:, arm] > r[:, torso]
    assert in_front[:30].all() and not in_front[30:].any()
    # near a tie the previous order is kept: depths jittering within ±0.9 around 0 never flip it
    z2 = _two_parts(np.r_[np.full(10, -5.0), noise[:50]])
    r2 = order_ranks(depth_orders(z2, hysteresis=1.0))
    assert (r2[:, arm] > r2[:, torso]).all()
    m = depth_metric(orders, z, margin=1.0)
    assert m["depth_agreement"] == 1.0 and m["order_flips"] >= 1


def test_fixed_constraints_and_stability():
    z = np.random.default_rng(1).normal(0, 10, (40, len(PARTS)))
    orders = depth_orders(z, hysteresis=0.0)
    r = order_ranks(orders)
    assert (r[:, PART_INDEX["head"]] > r[:, PART_INDEX["torso"]]).all()  # annotation: head over torso
    assert all(sorted(o) == list(range(len(PARTS))) for o in orders)
    # with no depth difference anywhere, nothing moves from the default order
    flat = depth_orders(np.zeros((5, len(PARTS))), hysteresis=1.0)
    assert (flat == default_order()).all()
    with pytest.raises(InputError, match="frame 2"):
        bad = np.zeros((4, len(PARTS)))
        bad[2, 3] = np.nan
        depth_orders(bad, 1.0)


def test_part_depths_are_means_of_their_key_points():
    zj = np.arange(17, dtype=float)[None].repeat(2, 0)
    zp = part_depths(zj)
    assert zp[0, PART_INDEX["l_forearm"]] == pytest.approx((12 + 13) / 2)
    with pytest.raises(InputError):
        part_depths(np.zeros((3, 16)))


# --------------------------------------------------------------------------- rendering

def test_rest_render_reproduces_the_drawing(figure, rig):
    img = rig.renderer(figure.shape).render(rig.mesh.vertices)
    a = img[..., 3] >= 128
    assert (a == figure.mask).mean() > 0.999 and not (figure.mask & ~a).any()
    inside = cv2.erode(figure.mask.astype(np.uint8), np.ones((3, 3))) > 0
    diff = np.abs(img[..., :3].astype(int) - figure.texture[..., :3].astype(int))[inside]
    assert diff.max() <= 1


def test_integer_translation_translates_the_image(figure, rig):
    r = rig.renderer((figure.shape[0] + 20, figure.shape[1] + 30))
    a = r.render(rig.mesh.vertices)
    b = r.render(rig.mesh.vertices + [30.0, 20.0])
    assert np.array_equal(b[20:, 30:], a[:-20, :-30])


@pytest.mark.parametrize("V", [np.array([[10.3, 12.7], [90.2, 30.1], [40.6, 95.4]]),
                               np.array([[10.3, 12.7], [40.6, 95.4], [90.2, 30.1]]),  # clockwise (a fold)
                               np.array([[-20.0, 50.5], [50.0, -30.0], [130.0, 120.0]])])  # past the edges
def test_a_triangle_covers_the_pixel_centres_inside_it_and_its_edge_pixels(V):
    # oracle: the sign of the three edge functions at every pixel centre
    tex = np.full((100, 100, 4), 255, np.uint8)
    img = _renderer(V, [[0, 1, 2]], [0], tex).render(V)
    y, x = np.mgrid[0:100, 0:100].astype(float)
    e = np.stack([(b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])
                  for a, b in ((V[0], V[1]), (V[1], V[2]), (V[2], V[0]))])
    inside = (e >= 0).all(0) | (e <= 0).all(0)
    drawn = img[..., 3] > 0
    assert not (inside & ~drawn).any()
    assert not (drawn & ~(cv2.dilate(inside.astype(np.uint8), np.ones((3, 3))) > 0)).any()


def test_triangles_that_share_an_edge_leave_no_pixel_between_them():
    """Any deformation of a connected mesh covers everything inside its outline: no crack."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(5)
    uv = rng.uniform(10, 90, (120, 2))
    T = Delaunay(uv).simplices
    tex = np.full((100, 100, 4), 255, np.uint8)
    r = _renderer(uv, T, np.zeros(len(T), int), tex, size=(140, 140))
    for k in range(5):   # a smooth, strong warp (no triangle flips, so no fold can open a hole)
        a = rng.uniform(0, 2 * np.pi)
        V = uv + 20 + 6 * np.column_stack([np.sin(uv[:, 1] / 15 + a), np.cos(uv[:, 0] / 13 - a)])
        drawn = r.render(V)[..., 3] > 0
        bg = (~drawn).astype(np.uint8)
        n, lab = cv2.connectedComponents(bg, connectivity=4)
        assert n == 2, "background enclosed by the mesh"


@pytest.mark.parametrize("corner", [(100.0, 99.0), (100.4, 99.3), (101.0, 99.0), (60.5, 59.8)])
def test_a_sliver_triangle_shows_only_its_own_texels(corner):
    """A triangle squashed to a sliver gets pixels along its outline whose centres lie outside it;
    its affine map would fetch their texels many pixels beyond the mesh (onto the page).  Each
    pixel shows a texel within a pixel of its own triangle's rest box."""
    yy, xx = np.mgrid[:200, :200]
    tex = np.dstack([xx, yy, np.zeros_like(xx), np.full_like(xx, 255)]).astype(np.uint8)  # texel = (x, y)
    uv = np.array([[80, 80], [120, 80], [120, 120], [80, 120]], float)
    r = _renderer(uv, [[0, 3, 2], [0, 2, 1]], [0, 0], tex)
    V = uv.copy()
    V[1] = corner                       # almost onto the diagonal 0-2: triangle (0, 2, 1) a sliver
    img = r.render(V)
    cov = img[..., 3] >= 128
    u, v = img[..., 0][cov].astype(int), img[..., 1][cov].astype(int)
    assert cov.sum() > 800
    assert u.min() >= 79 and u.max() <= 121 and v.min() >= 79 and v.max() <= 121


@pytest.mark.parametrize("C", [(101.5, 80.0), (100.8, 81.0), (98.5, 80.0)])
def test_a_squashed_triangle_shows_texels_within_a_pixel_of_itself_not_of_its_box(C):
    """The rest triangle (80, 80), (120, 120), (120, 80) fills half its box.  Squashed to a needle a
    pixel or two wide (folded when C passes the long edge), the pixels the fill gives it beside the
    needle must show the triangle's own texels (u ≥ v, within a pixel), not the empty half of its
    box (u < v), where the colour of a limb lying beside it may be."""
    yy, xx = np.mgrid[:200, :200]
    tex = np.dstack([xx, yy, np.zeros_like(xx), np.full_like(xx, 255)]).astype(np.uint8)  # texel = (x, y)
    uv = np.array([[80, 80], [120, 120], [120, 80]], float)
    V = np.array([[100.0, 80.0], [100.5, 120.0], C])
    img = _renderer(uv, [[0, 1, 2]], [0], tex).render(V)
    cov = img[..., 3] >= 128
    u, v = img[..., 0][cov].astype(float), img[..., 1][cov].astype(float)
    assert cov.sum() >= 40
    assert ((v - u) / np.sqrt(2)).max() <= 1.0 + 1.0     # REACH, and a pixel of texel rounding


def test_depth_order_decides_which_part_is_seen():
    # two overlapping squares, parts torso (red) and l_forearm (blue)
    V = np.array([[0, 0], [40, 0], [40, 40], [0, 40], [20, 20], [60, 20], [60, 60], [20, 60]], float)
    T = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    tex = np.zeros((70, 70, 4), np.uint8)
    tex[:45, :45] = (255, 0, 0, 255)
    tex[15:65, 15:65] = (0, 0, 255, 255)
    uv = V.copy()
    uv[:4] = uv[:4] * 0.25 + 2
    uv[4:] = (uv[4:] - 20) * 0.25 + 40
    parts = np.array([PART_INDEX["torso"]] * 2 + [PART_INDEX["l_forearm"]] * 2)
    r = _renderer(uv, T, parts, tex, size=(70, 70))
    arm_front = r.render(V, order=[PART_INDEX["torso"], PART_INDEX["l_forearm"]])
    arm_back = r.render(V, order=[PART_INDEX["l_forearm"], PART_INDEX["torso"]])
    assert tuple(arm_front[30, 30, :3]) == (0, 0, 255)
    assert tuple(arm_back[30, 30, :3]) == (255, 0, 0)
    assert arm_front[66, 66, 3] == 0


def test_a_soft_edge_over_a_part_shows_that_part_not_the_paper():
    # A limb's anti-aliased outline (texels of alpha 128) laid over the torso blends with the
    # torso's colour; blended with the paper it would draw a light hairline along the limb.
    V = np.array([[0, 0], [40, 0], [40, 40], [0, 40], [20, 20], [60, 20], [60, 60], [20, 60]], float)
    T = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    tex = np.zeros((70, 140, 4), np.uint8)
    tex[:, :70] = (255, 0, 0, 255)           # torso: opaque red
    tex[:, 70:] = (0, 0, 255, 255)           # limb: opaque blue ...
    tex[:, 88:92] = (0, 0, 255, 128)         # ... with a soft rim of half alpha
    uv = V.copy()
    uv[4:, 0] += 70
    parts = np.array([PART_INDEX["torso"]] * 2 + [PART_INDEX["l_forearm"]] * 2)
    r = _renderer(uv, T, parts, tex, size=(70, 70))
    out = r.render(V, order=[PART_INDEX["torso"], PART_INDEX["l_forearm"]], background=(255, 255, 255))
    over_torso, over_paper = out[30, 20].astype(int), out[50, 20].astype(int)
    assert over_torso[1] <= 2 and abs(over_torso[0] - 127) <= 2 and abs(over_torso[2] - 128) <= 2
    assert abs(over_paper[1] - 127) <= 2     # where nothing lies under the rim, the paper shows
    assert tuple(out[30, 30]) == (0, 0, 255)


def test_overlaps_from_boxes(rig):
    V = rig.mesh.vertices[None]
    ov = part_overlaps(V, rig.mesh.triangles, rig.mesh.parts)
    assert ov[0, PART_INDEX["l_upper_arm"], PART_INDEX["l_forearm"]]
    assert not ov[0, PART_INDEX["l_forearm"], PART_INDEX["r_forearm"]]
    assert (ov == ov.transpose(0, 2, 1)).all()


# --------------------------------------------------------------------------- files

def test_gif_of_few_colours_is_exact_and_its_page_stays_white(tmp_path):
    imgs = np.full((6, 30, 50, 4), 0, np.uint8)  # transparent page: composited over white
    for t in range(6):
        imgs[t, 5:25, 4 * t: 4 * t + 10] = (200, 50, 20, 255)
        imgs[t, 10:14, 30:34] = (10, 120 + 20 * t, 240, 255)
    back = read_gif(write_gif(tmp_path / "a.gif", imgs, fps=12))
    want = np.where(imgs[..., 3:] > 0, imgs[..., :3], 255)
    assert back.shape == want.shape and np.array_equal(back, want)


def test_gif_shares_one_palette_so_still_pixels_do_not_flicker(tmp_path):
    # More colours than a GIF holds: a gradient patch sliding over a white page, its colours
    # shifting from frame to frame.  A palette per frame rounds the still pixels differently
    # from one frame to the next; one palette cannot.
    T, yy, xx = 12, *np.mgrid[:40, :40]
    imgs = np.full((T, 60, 90, 3), 255, np.uint8)
    for t in range(T):
        imgs[t, 10:50, 20 + 2 * t: 60 + 2 * t] = np.dstack([yy * 6, xx * 6, (yy + xx + 4 * t) * 3]).astype(np.uint8)
    imgs[:, 52:58, 5:85] = np.linspace(0, 250, 80).astype(np.uint8)[None, None, :, None]  # a still grey ramp
    back = read_gif(write_gif(tmp_path / "g.gif", imgs, fps=12))
    page = (imgs == 255).all(-1)
    assert np.array_equal(back[page], imgs[page])
    still = (imgs[1:] == imgs[:-1]).all(-1)
    assert not ((back[1:] != back[:-1]).any(-1) & still).any()
    err = np.abs(back.astype(int) - imgs)[~page].mean()
    assert err < 8.0, err


def test_writers_round_trip_and_are_atomic(tmp_path):
    rng = np.random.default_rng(0)
    imgs = np.zeros((5, 31, 40, 3), np.uint8)
    for t in range(5):
        imgs[t, :, 5 * t: 5 * t + 8] = (200, 50, 20)
        imgs[t, 0, 0] = rng.integers(0, 255, 3)
    files = write_png_frames(tmp_path / "frames", imgs)
    assert len(files) == 5
    back = cv2.cvtColor(cv2.imread(str(files[3])), cv2.COLOR_BGR2RGB)
    assert np.array_equal(back, imgs[3])
    gif = write_gif(tmp_path / "a.gif", imgs, fps=10)
    from PIL import Image

    with Image.open(gif) as im:
        assert im.n_frames == 5 and im.size == (40, 31)
    mp4 = write_mp4(tmp_path / "a.mp4", imgs, fps=10)
    cap = cv2.VideoCapture(str(mp4))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    assert n == 5
    # same inputs, same bytes (no timestamps)
    write_gif(tmp_path / "b.gif", imgs, fps=10)
    assert (tmp_path / "a.gif").read_bytes() == (tmp_path / "b.gif").read_bytes()
    # a failing writer leaves nothing behind
    with pytest.raises(Exception):
        write_png_frames(tmp_path / "bad", [imgs[0], np.zeros((3, 3, 7), np.uint8)])
    assert not (tmp_path / "bad").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "a.mp4", "b.gif", "frames"]


# --------------------------------------------------------------------------- outline redraw

def _outlined_disc(size=360, radius=150, line=5, paper=2):
    """An RGBA drawing: a grey disc with a dark outline `line` px thick, `paper` px inside the mask's edge."""
    yy, xx = np.mgrid[:size, :size]
    r = np.hypot(xx - size / 2, yy - size / 2)
    mask = r <= radius
    tex = np.zeros((size, size, 4), np.uint8)
    tex[..., 3] = 255
    tex[..., :3] = 235                                   # paper
    tex[r <= radius - paper, :3] = (40, 30, 90)          # the line
    tex[r <= radius - paper - line, :3] = 150            # the fill
    return tex, mask
