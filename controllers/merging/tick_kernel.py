"""The V2X merging controller's CAM stage, delivery and fuse, and coordination of a tick in one compiled call
(issue 27, the ninth CPU pass).

Inside a run a compiled call costs 15-40 us whatever it does (SUMO's step evicts the caches between two
ticks), so the three stages that were three calls (``cam_kernel.cam_pose_tick_into``,
``node_pool._deliver_fuse_tick`` with ``referenced_in_order``, ``coord_kernel.coordinate_into``) are one
here, with the tick's send, in the former order:

1. the CAM stage; a status > 0 (a listener to attach or detach, a node or a schedule missing) returns at
   once with nothing done, as the stage alone does (the caller admits in Python and calls again);
2. the channel's delivery, the fuse of the tick's CAMs into the tracks (on the listen keys the stage just
   wrote) and the stale tracks' drop, then the delivered references in the order (arrival, send order);
   intervals missing from the process-noise table return (the caller completes the fuse and coordinates
   on its own, as before);
3. the crossing speed (``V2XMerging._stream_speed``: the mean of the stage's upstream mainline speeds,
   clipped to [8, v_max], unless the target is given) and the coordination on the stage's rows; a tie of
   the FCFS keys or a short pool of sensor draws returns (the caller coordinates and sends, as before);
4. the tick's CAMs and an assignment per connected slot in one send (``AddressedChannel.send``'s two
   kernels on the channel's pool of uniforms: the same draws as its ``rng.random`` per send); the caller
   keeps the assignments its references stand for.

Only the deterministic default is fused: the controller keeps the separate calls for a channel without
delay (its CAMs are sent between the stage and the delivery) and the Python coordinator (a ``SlotCheck``).
"""

from __future__ import annotations

import math
from typing import Any

from numba import njit, types
from numba.core import sigutils

from corridor.addressed_channel import draw_and_enqueue, find_copies
from corridor.controllers.merging.cam_kernel import STATUS_OK, _pose_tick_signature, cam_pose_tick_into
from corridor.controllers.merging.coord_kernel import _COORD_SIG, HAVE_C_POW, coordinate_into
from corridor.vehicles.tracks.node_pool import _DELIVER_SIG, _deliver_fuse_tick, referenced_in_order

NOT_RUN = -1  # a stage the call did not reach (see fused_tick_into)
_NO_SEND = (NOT_RUN, 0, 0, 0, 0, 0, 0, 0, 0)

_DLV_OWN = (*range(17), 18, *range(22, 41))  # _deliver_fuse_tick's arguments the stage does not share
_CRD_OWN = (6, 8, 12, *range(14, 24))  # coordinate_into's arguments the others do not share


def _signature() -> Any:
    cam = _pose_tick_signature()
    dlv_args, dlv_ret = sigutils.normalize_signature(_DELIVER_SIG)
    crd_args, crd_ret = sigutils.normalize_signature(_COORD_SIG)
    i8, f8 = types.int64, types.float64
    b1, vi = types.boolean, types.int64[:]
    send = (b1, f8, vi, vi, b1[:], vi, f8[:], b1[:, :], f8, i8, f8, f8, i8, f8[:], i8)
    args = (*cam.args, *(dlv_args[j] for j in _DLV_OWN), *(crd_args[j] for j in _CRD_OWN), f8[:], i8[:, :], f8, f8,
            *send)
    return types.Tuple((cam.return_type, dlv_ret, i8, crd_ret, f8, types.UniTuple(i8, 9)))(*args)


@(njit(_signature(), cache=True) if HAVE_C_POW else njit(cache=True))
def fused_tick_into(t, ref_xy, back, cos_yaw, sin_yaw, size, front_x, pos, role, uid, conn_of, on_ramp_lane,
                    joins_lane, merged_lane, ramp_code, cos_ramp, dist, connected, ramp, right, merged, speed,
                    row_node, near_lo, near_hi, zone_lo, zone_hi, stream_lo, stream_hi, slot_of, n_vehicle_rx, next_s,
                    period, known, chan_pos, rsu, x_rsu, y_rsu, order_node, depth, fifo, r0, lane, lane_pos, near,
                    src, cam_pos, val, ref, ptr, dst, keys, cand, leader, sp, due, newcomers, d_t_due, d_attached,
                    d_n_fl, d_q_seq, d_q_src, d_q_dst, d_q_t_sent, d_q_t_recv, d_q_val, d_q_ref, d_o_seq, d_o_src,
                    d_o_dst, d_o_t_sent, d_o_t_recv, d_o_val, d_o_ref, d_stale_after_s, d_n_free, d_row_of, d_r, d_x,
                    d_p, d_t_row, d_row_slot, d_row_src, d_free, d_upd_row, d_upd_z, d_upd_dt, d_ahead, d_q_dt, d_q11,
                    d_q12, d_q22, d_at, d_missing, c_row_key, c_rsu_slot, c_z_noise, c_entered_of, c_s_int, c_s_flt,
                    c_si, c_sf, c_cfg, c_cfg_int, c_z_int, c_z_flt, c_slot_out, ref_t, ref_dr, target_given, v_max,
                    send, s_r2, s_entry_of, s_dst, s_near, s_counts, s_loss, s_ge_bad, s_t_last, s_max_in_flight,
                    s_latency, s_jitter, s_seq0, s_pool, s_pool_at):  # type: ignore[no-untyped-def]
    """The three stages (see the module docstring), flat: ``cam_pose_tick_into``'s arguments, then those of
    ``_deliver_fuse_tick`` (``d_``) and ``coordinate_into`` (``c_``) that the stage does not share (the
    delivery's listen keys are the stage's ``keys``; the coordination's rows the stage's buffers, its RSU
    tracks the delivery's), ``referenced_in_order``'s outputs (``ref_t``, ``ref_dr``), the target speed
    given [m/s] (NaN: the crossing speed) and ``v_max`` [m/s]; with ``send`` the tick's send after a coordination
    done here (``s_``: ``AddressedChannel.send_buffers``' arguments after its range arrays, which the stage and
    the delivery share). (One flat list: a tuple argument is typed by numba's dispatcher in Python, ~50 us a
    call here, an array or a scalar in C.)

    Returns (the stage's counts, the delivery's (copies, updates, free rows, missing intervals), the
    delivered references, the coordination's (status, zone, slots), the target [m/s], the send's (1: sent,
    copies in flight, next send order, copies, in range, lost, late, overflow, uniforms read)); a stage not
    reached has ``NOT_RUN`` as its first count."""
    r_cam = cam_pose_tick_into(t, ref_xy, back, cos_yaw, sin_yaw, size, front_x, pos, role, uid, conn_of,
                               on_ramp_lane, joins_lane, merged_lane, ramp_code, cos_ramp, dist, connected, ramp,
                               right, merged, speed, row_node, near_lo, near_hi, zone_lo, zone_hi, stream_lo,
                               stream_hi, slot_of, n_vehicle_rx, next_s, period, known, chan_pos, rsu, x_rsu, y_rsu,
                               order_node, depth, fifo, r0, lane, lane_pos, near, src, cam_pos, val, ref, ptr, dst,
                               keys, cand, leader, sp, due, newcomers)
    if r_cam[0] != STATUS_OK:
        return r_cam, (NOT_RUN, 0, 0, 0), 0, (NOT_RUN, 0, 0), math.nan, _NO_SEND
    n_keys, n_c, stream_sum, n_s = r_cam[5], r_cam[6], r_cam[7], r_cam[8]
    n = ref_xy.shape[0]
    r_dlv = _deliver_fuse_tick(d_t_due, d_attached, d_n_fl, d_q_seq, d_q_src, d_q_dst, d_q_t_sent, d_q_t_recv,
                               d_q_val, d_q_ref, d_o_seq, d_o_src, d_o_dst, d_o_t_sent, d_o_t_recv, d_o_val, d_o_ref,
                               t, d_stale_after_s, rsu, slot_of, keys[:n_keys], d_n_free, d_row_of, d_r, d_x, d_p,
                               d_t_row, d_row_slot, d_row_src, d_free, d_upd_row, d_upd_z, d_upd_dt, d_ahead, d_q_dt,
                               d_q11, d_q12, d_q22, d_at, d_missing)
    n_due = r_dlv[0]
    k_refs = referenced_in_order(d_o_t_recv, d_o_seq, d_o_dst, d_o_ref, n_due, ref_t, ref_dr) if n_due else 0
    if r_dlv[3]:  # intervals missing from the table: the fuse is completed by the caller
        return r_cam, r_dlv, k_refs, (NOT_RUN, 0, 0), math.nan, _NO_SEND
    if math.isnan(target_given):  # V2XMerging._stream_speed: np.mean's bits (sum / n), then np.clip's value
        v = stream_sum / n_s if n_s else v_max
        v = 8.0 if 8.0 > v else v  # Python's max(v, 8.0)
        target = v_max if v_max < v else v  # Python's min(v, v_max)
    else:
        target = target_given
    r_crd = coordinate_into(t, cand[:n_c], connected[:n], dist[:n], speed, ramp[:n], c_row_key, row_node, c_rsu_slot,
                            d_row_of, d_x, d_t_row, c_z_noise, target, c_entered_of, c_s_int, c_s_flt, c_si, c_sf,
                            c_cfg, c_cfg_int, c_z_int, c_z_flt, c_slot_out)
    if not send or r_crd[0] != STATUS_OK:  # a tie or short draws: the caller coordinates and sends
        return r_cam, r_dlv, k_refs, r_crd, target, _NO_SEND
    # V2XMerging._send: the due CAMs, then an assignment per connected slot in order (the room after the CAMs:
    # its receiver the slot's row's node), in one AddressedChannel.send on the pool's uniforms
    n_due, m = r_cam[2], r_cam[4]
    n_a = 0
    if r_crd[1] > 0:  # a zone: assignments
        for j in range(r_crd[2]):
            if c_slot_out[j, 2] != 0:
                dst[m + n_a] = row_node[c_slot_out[j, 1]]
                n_a += 1
    n_e = n_due + n_a
    n_fl = d_o_seq[d_o_seq.shape[0] - 1]  # the copies in flight after the delivery
    if n_e == 0 or ptr[n_e] == 0:  # nothing to send, or nothing listed (send draws nothing)
        return r_cam, r_dlv, k_refs, r_crd, target, (1, n_fl, s_seq0, 0, 0, 0, 0, 0, 0)
    counts = s_counts[:n_e]
    n_c, n_near = find_copies(src[:n_e], cam_pos[:n_e], ptr[:n_e + 1], dst[:m + n_a], d_attached, known, chan_pos,
                              s_r2, s_entry_of, s_dst, s_near, counts)
    n_u = 2 * n_c + (n_near if s_loss.shape[0] == 4 else 0)
    room = s_max_in_flight - n_fl
    r = draw_and_enqueue(t, t + s_latency, s_jitter, s_loss, s_ge_bad, s_t_last, room if room > 0 else 0, s_seq0,
                         n_fl, src[:n_e], s_entry_of[:n_c], s_dst[:n_c], s_near[:n_c], s_pool[s_pool_at:s_pool_at + n_u],
                         counts, val[:n_e], ref[:n_e], d_q_seq, d_q_src, d_q_dst, d_q_t_sent, d_q_t_recv, d_q_val,
                         d_q_ref)
    return r_cam, r_dlv, k_refs, r_crd, target, (1, r[0], r[1], n_c, n_near, r[2], r[3], r[4], n_u)


# the compiled overload's entry point: called directly, it skips the dispatcher's typing of the 126 arguments
# (~2.5 us of the ~7 us a call costs on its arguments alone; the eleventh CPU pass), and unboxes them for the
# one signature it was compiled for (explicit, above), so the caller must pass exactly those types (tested on
# every call of real runs: tests/controllers/test_ctrl_merging_tick_kernel.py); without the explicit signature
# (no powf64) the dispatcher itself is called
FUSED_TICK = (fused_tick_into.overloads[fused_tick_into.signatures[0]].entry_point if HAVE_C_POW
              else fused_tick_into)
