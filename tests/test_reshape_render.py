"""Depth order, textured-mesh rendering and the animation writers."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from nnsf.errors import InputError
from nnsf.reshape.character import stick_figure
from nnsf.reshape.depth import (
    default_order, depth_metric, depth_orders, order_ranks, part_depths, part_overlaps,
)
from nnsf.reshape.parts import PARTS, PART_INDEX
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.video import read_gif, write_gif, write_mp4, write_png_frames
from nnsf.reshape.rig import Rig


@pytest.fixture(scope="module")
def figure():
    return stick_figure(height=240)


@pytest.fixture(scope="module")
def rig(figure):
    return Rig.build(figure, n_vertices=400, split="layered", propagation="limb-frame")


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
    r = MeshRenderer.for_mesh(rig.mesh, figure)
    img = r.render(rig.mesh.vertices)
    a = img[..., 3] >= 128
    inter = (a & figure.mask).sum()
    assert inter / (a | figure.mask).sum() > 0.95
    both = a & figure.mask & (cv2.erode(figure.mask.astype(np.uint8), np.ones((5, 5))) > 0)
    diff = np.abs(img[..., :3].astype(int) - figure.texture[..., :3].astype(int))[both]
    assert diff.mean() < 2.0


def test_integer_translation_translates_the_image(figure, rig):
    r = MeshRenderer.for_mesh(rig.mesh, figure, size=(figure.shape[0] + 20, figure.shape[1] + 30))
    a = r.render(rig.mesh.vertices)
    b = r.render(rig.mesh.vertices + [30.0, 20.0])
    assert np.array_equal(b[20:, 30:], a[:-20, :-30])


@pytest.mark.parametrize("V", [np.array([[10.3, 12.7], [90.2, 30.1], [40.6, 95.4]]),
                               np.array([[10.3, 12.7], [40.6, 95.4], [90.2, 30.1]]),  # clockwise (a fold)
                               np.array([[-20.0, 50.5], [50.0, -30.0], [130.0, 120.0]])])  # past the edges
def test_scanline_coverage_is_the_pixel_centres_inside(V):
    # oracle: the sign of the three edge functions at every pixel centre
    tex = np.full((100, 100, 4), 255, np.uint8)
    r = MeshRenderer(V, np.array([[0, 1, 2]]), np.array([0]), tex)
    _, _, ids = r.maps(V)
    y, x = np.mgrid[0:100, 0:100].astype(float)
    e = []
    for a, b in ((V[0], V[1]), (V[1], V[2]), (V[2], V[0])):
        e.append((b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]))
    e = np.stack(e)
    inside = (e >= 0).all(0) | (e <= 0).all(0)
    assert np.array_equal(ids >= 0, inside)


def test_depth_order_decides_which_part_is_seen():
    # two overlapping squares, parts torso (red) and l_forearm (blue)
    V = np.array([[0, 0], [40, 0], [40, 40], [0, 40], [20, 20], [60, 20], [60, 60], [20, 60]], float)
    T = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    tex = np.zeros((70, 70, 4), np.uint8)
    tex[:45, :45] = (255, 0, 0, 255)
    tex[15:65, 15:65] = (0, 0, 255, 255)
    # texture coordinates: the first square samples red, the second blue
    uv = V.copy()
    uv[:4] = uv[:4] * 0.25 + 2
    uv[4:] = (uv[4:] - 20) * 0.25 + 40
    parts = np.array([PART_INDEX["torso"]] * 2 + [PART_INDEX["l_forearm"]] * 2)
    r = MeshRenderer(uv, T, parts, tex, size=(70, 70))
    arm_front = r.render(V, order=[PART_INDEX["torso"], PART_INDEX["l_forearm"]])
    arm_back = r.render(V, order=[PART_INDEX["l_forearm"], PART_INDEX["torso"]])
    assert tuple(arm_front[30, 30, :3]) == (0, 0, 255)
    assert tuple(arm_back[30, 30, :3]) == (255, 0, 0)
    assert arm_front[65, 65, 3] == 0


def test_soft_rim_over_a_part_shows_that_part_not_the_paper():
    # A limb's anti-aliased outline (texels of alpha 128) laid over the torso must blend with the
    # torso's colour; blended with the paper it draws a light hairline along the limb.
    V = np.array([[0, 0], [40, 0], [40, 40], [0, 40], [20, 20], [60, 20], [60, 60], [20, 60]], float)
    T = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    tex = np.zeros((70, 140, 4), np.uint8)
    tex[:, :70] = (255, 0, 0, 255)           # torso: opaque red
    tex[:, 70:] = (0, 0, 255, 255)           # limb: opaque blue ...
    tex[:, 88:92] = (0, 0, 255, 128)         # ... with a soft rim of half alpha
    uv = V.copy()
    uv[4:, 0] += 70
    parts = np.array([PART_INDEX["torso"]] * 2 + [PART_INDEX["l_forearm"]] * 2)
    r = MeshRenderer(uv, T, parts, tex, size=(70, 70))
    out = r.render(V, order=[PART_INDEX["torso"], PART_INDEX["l_forearm"]], background=(255, 255, 255))
    over_torso, over_paper = out[30, 20].astype(int), out[50, 20].astype(int)
    # half blue over red: no green (the paper is the only green source)
    assert over_torso[1] <= 2 and abs(over_torso[0] - 127) <= 2 and abs(over_torso[2] - 128) <= 2
    # where nothing lies under the rim, the paper does show through it
    assert abs(over_paper[1] - 127) <= 2
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


def test_outline_style_reads_colour_width_and_paper_margin():
    from nnsf.reshape.render import outline_style

    tex, mask = _outlined_disc()
    rgb, width, paper = outline_style(tex, mask)
    assert np.allclose(rgb, (40, 30, 90), atol=1)
    assert abs(width - 5) <= 1 and abs(paper - 2) <= 1
    flat = tex.copy()
    flat[mask, :3] = 150  # no outline at all: nothing to redraw
    assert outline_style(flat, mask) is None


def test_outline_is_redrawn_along_new_edges_only():
    """Cut the disc in half with a straight edge through its middle: the cut (texels deep inside
    the drawing) gets a stroke of the outline's colour, the drawn arc keeps its own pixels."""
    from nnsf.reshape.render import MeshRenderer, outline_style

    tex, mask = _outlined_disc()
    H, W = mask.shape
    half = mask.copy()
    half[:, W // 2:] = False
    # one triangle fan over the left half-disc; rest positions = texture coordinates
    ang = np.linspace(np.pi / 2, 3 * np.pi / 2, 40)
    rim = np.column_stack([W / 2 + 150 * np.cos(ang), H / 2 + 150 * np.sin(ang)])
    V = np.vstack([[W / 2, H / 2], rim])
    T = np.array([[0, k, k + 1] for k in range(1, len(rim))])
    style = outline_style(tex, mask)
    r = MeshRenderer(V, T, np.zeros(len(T), np.int64), tex, mask, reink=style)
    r0 = MeshRenderer(V, T, np.zeros(len(T), np.int64), tex, mask)
    a, b = r.render(V), r0.render(V)
    lum = a[..., :3].astype(float) @ [0.299, 0.587, 0.114]
    cut = (np.abs(np.arange(W)[None, :] - W / 2) <= 2) & (np.abs(np.arange(H)[:, None] - H / 2) < 120)
    assert (lum[cut & (a[..., 3] > 128)] < 90).mean() > 0.9        # the cut is inked
    arc = half & ~cv2.erode(half.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    arc &= np.abs(np.arange(W)[None, :] - W / 2) > 12                  # away from the cut's ends
    assert np.array_equal(a[arc], b[arc])                             # the drawn outline is untouched


def test_a_short_unlined_notch_is_inked_inside_the_silhouette_only():
    """A 10 px stretch of edge whose texels are a joint tab's (deep inside the drawing), between two
    drawn outline ends: shorter than three line widths, it is still inked, within the silhouette; a
    run of the same length just past the depth threshold is the outline's wiggle and stays."""
    from nnsf.reshape.outline import redraw_outline

    h, w = 60, 80
    crop = np.zeros((h, w, 4), np.uint8)
    crop[10:50, 10:70] = (150, 150, 150, 255)              # premultiplied, opaque
    rgb, width, paper = np.array([40.0, 30.0, 90.0], np.float32), 6.0, 0.0   # min run 18 points
    depth = np.zeros((h, w), np.float32)
    depth[10, 30:40] = 1e3                                 # the tab's edge along the top side
    depth[49, 30:40] = paper + 0.5 * width + 2.5           # just past the threshold (5 px)
    out = redraw_outline(crop, depth, (rgb, width, paper))
    assert (out[:10, :, 3] == 0).all() and (out[50:, :, 3] == 0).all()   # nothing outside
    lum = out[..., :3].astype(float) @ [0.299, 0.587, 0.114]
    assert (lum[10:13, 31:39] < 60).all()                  # the notch is inked
    assert np.array_equal(out[44:, :], crop[44:, :])       # the wiggle is left alone
    assert np.array_equal(out[20:40, :], crop[20:40, :])   # and nothing else changes


def test_a_new_edge_is_inked_inside_and_crosses_only_a_narrow_gap():
    """A cut's edge (texels deep inside the drawing) along a straight side is inked a full line
    width deep inside the silhouette with nothing outside it (the drawn outline lies inside the
    silhouette too: a stroke centred on the edge was a bump beside it); across a notch narrower
    than the line (a gap between two pieces at a joint) the stroke closes the silhouette."""
    from nnsf.reshape.outline import redraw_outline

    h, w = 80, 120
    crop = np.zeros((h, w, 4), np.uint8)
    crop[20:60, 10:110] = (150, 150, 150, 255)             # premultiplied, opaque
    crop[20:30, 58:61] = 0                                  # a 3 px gap, 10 px deep, in the top side
    rgb, width, paper = np.array([40.0, 30.0, 90.0], np.float32), 6.0, 0.0
    depth = np.zeros((h, w), np.float32)
    depth[20, 10:110] = 1e3                                 # the top side and the gap's walls: a cut's
    depth[20:31, 57:62] = 1e3                               # texels
    out = redraw_outline(crop, depth, (rgb, width, paper))
    assert (out[:20, :, 3] == 0).all()                      # no ink beyond the straight edge
    lum = out[..., :3].astype(float) @ [0.299, 0.587, 0.114]
    assert (lum[20:25, 16:52] < 60).all() and (lum[20:25, 67:104] < 60).all()   # a line width deep
    assert (out[21:30, 58:61, 3] > 200).all()               # the gap is closed ...
    assert (lum[21:30, 58:61] < 60).all()                   # ... with ink
    for cols in (slice(16, 48), slice(72, 104)):            # away from the gap, below the line
        assert np.array_equal(out[30:, cols], crop[30:, cols])      # the fill is left alone

