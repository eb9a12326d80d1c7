"""One geometry pass over samples in numpy: the envelope's check when it runs without the
compiled kernels (`Envelope(compiled=False)`), and the kernels' test oracle
(tests/safety/test_geometry_kernel.py holds both to the same findings, word for word)."""

from __future__ import annotations

import numpy as np

from armwarden.core import geometry
from armwarden.robot.model import RobotModel
from armwarden.safety.bodies import CheckedBodies
from armwarden.safety.findings import LEAVES_WORKSPACE, Found, enters, first_per_body, self_collision
from armwarden.safety.sampling import Samples
from armwarden.safety.violations import Code


def geometry_pass(robot: RobotModel, bodies: CheckedBodies, samples: Samples, segments: bool = True
                  ) -> tuple[Found, np.ndarray, np.ndarray]:
    """One check of consecutive samples. Returns the first violation per (code, body, what)
    — per body name its earliest sample's (at it, the lowest-indexed body's) —, which samples
    found anything, and the TCP positions. Every keep-out candidate of the broad phase is
    confirmed exactly (`_confirm_keep_out`). `segments`: the TCP's straight segment from
    the sample before counts too (False: the samples are separate configurations)."""
    t_s, q_s, inflation = samples.times, samples.positions, samples.inflation
    p0, p1 = robot.body_points(robot.joint_frames(q_s))  # (N, B+1, 3); last body is the TCP point
    tcp = p0[:, -1]
    radius = inflation + bodies.padded_radii  # (N, B+1)
    found: Found = {}
    flagged = np.zeros(len(t_s), dtype=bool)

    # axis-aligned bounds of every padded, inflated capsule: the broad phase for everything below
    lo, hi = geometry.capsule_bounds(p0, p1, radius)

    # workspace: every capsule and the TCP entirely inside the box (exact for capsules)
    outside = ~geometry.bounds_inside(lo, hi, bodies.workspace_lo, bodies.workspace_hi) & bodies.moving
    flagged |= np.any(outside, axis=1)
    first_per_body(bodies, found, outside, t_s, p0, Code.WORKSPACE, LEAVES_WORKSPACE)

    # keep-out: bounds that overlap a zone are confirmed exactly (capsule–box distance)
    if len(bodies.keep_out):
        ko_lo, ko_hi = bodies.keep_out_lo, bodies.keep_out_hi
        overlap = np.all(lo[:, :, None] <= ko_hi, axis=-1) & np.all(hi[:, :, None] >= ko_lo, axis=-1)
        overlap &= bodies.moving[None, :, None]
        if segments and len(tcp) > 1:  # the TCP's straight segments between samples, too
            r_tcp = radius[1:, -1, None]
            seg_lo = np.minimum(tcp[:-1], tcp[1:]) - r_tcp
            seg_hi = np.maximum(tcp[:-1], tcp[1:]) + r_tcp
            overlap[1:, -1] |= np.all(seg_lo[:, None] <= ko_hi, axis=-1) & np.all(seg_hi[:, None] >= ko_lo, axis=-1)
        if np.any(overlap):
            confirmed = _confirm_keep_out(bodies, overlap, p0, p1, radius, tcp, segments)
            flagged |= np.any(confirmed, axis=(1, 2))
            for zone_index, zone in enumerate(bodies.keep_out):
                first_per_body(bodies, found, confirmed[:, :, zone_index], t_s, p0, Code.KEEP_OUT, enters(zone))

    # self-collision: capsule pairs closer than the sum of their inflated radii
    if len(bodies.pairs):
        flagged |= _check_self_collision(bodies, found, t_s, p0, p1, samples.pair_inflation)
    return found, flagged, tcp


def _confirm_keep_out(bodies: CheckedBodies, overlap: np.ndarray, p0: np.ndarray, p1: np.ndarray, radius: np.ndarray,
                      tcp: np.ndarray, segments: bool) -> np.ndarray:
    """Exact test of the broad-phase candidates, all at once: each capsule's distance to the
    zone against its radius, and for the TCP also (`segments`) its straight segment from the
    previous sample."""
    confirmed = np.zeros_like(overlap)
    k, body, zone = np.nonzero(overlap)
    zone_lo, zone_hi, r = bodies.keep_out_lo[zone], bodies.keep_out_hi[zone], radius[k, body]
    hit = geometry.segment_box_distance(p0[k, body], p1[k, body], zone_lo, zone_hi) <= r
    segment = ~hit & (body == radius.shape[1] - 1) & (k > 0) & segments  # the TCP, between samples
    if np.any(segment):
        ks, rs = k[segment], r[segment, None]
        hit[segment] = geometry.segments_hit_boxes(tcp[ks - 1], tcp[ks], zone_lo[segment] - rs, zone_hi[segment] + rs)
    confirmed[k, body, zone] = hit
    return confirmed


def _check_self_collision(bodies: CheckedBodies, found: Found, t_s: np.ndarray, p0: np.ndarray, p1: np.ndarray,
                          pair_inflation: np.ndarray) -> np.ndarray:
    """Adds the first self-collision per pair to `found`; returns which samples had one."""
    a, b = bodies.pairs[:, 0], bodies.pairs[:, 1]
    # broad phase: bounding spheres of the capsules (centre, half length + radius + inflation)
    centers = (p0[:, :-1] + p1[:, :-1]) / 2.0
    gap = centers[:, a] - centers[:, b]
    center_distance = np.sqrt(np.einsum("npi,npi->np", gap, gap))
    candidates = center_distance < bodies.pair_sphere_reach + pair_inflation  # (N, P)
    flagged = np.zeros(len(t_s), dtype=bool)
    if not np.any(candidates):
        return flagged
    k_idx, pair_idx = np.nonzero(candidates)
    pa, pb = a[pair_idx], b[pair_idx]
    dist = geometry.segment_segment_distance(p0[k_idx, pa], p1[k_idx, pa], p0[k_idx, pb], p1[k_idx, pb])
    allowed = bodies.pair_radii[pair_idx] + pair_inflation[k_idx, pair_idx]
    touching = dist < allowed
    flagged[k_idx[touching]] = True
    for i in np.flatnonzero(touching):  # sorted by sample, so the first hit per pair comes first
        pair = int(pair_idx[i])
        name_a, name_b = bodies.names[a[pair]], bodies.names[b[pair]]
        key = (Code.SELF_COLLISION.value, f"{name_a}|{name_b}", "")
        if key in found:
            continue
        found[key] = self_collision(bodies, pair, float(dist[i]), float(allowed[i]), float(t_s[k_idx[i]]))
    return flagged
