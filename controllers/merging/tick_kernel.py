"""The V2X merging controller's CAM stage, delivery and fuse, and coordination of a tick in one compiled call
(issue 27, the ninth CPU pass).

Inside a run a compiled call costs 15-40 us whatever it does (SUMO's step evicts the caches between two
ticks), so the three stages that were three calls (``cam_kernel.cam_pose_tick_into``,
``node_pool._deliver_fuse_tick`` with ``referenced_in_order``, ``coord_kernel.coordinate_into``) are one
here, each on its own arguments (passed as one tuple per stage) in the former order:

1. the CAM stage; a status > 0 (a listener to attach or detach, a node or a schedule missing) returns at
   once with nothing done, as the stage alone does (the caller admits in Python and calls again);
2. the channel's delivery, the fuse of the tick's CAMs into the tracks (on the listen keys the stage just
   wrote) and the stale tracks' drop, then the delivered references in the order (arrival, send order);
   intervals missing from the process-noise table return (the caller completes the fuse and coordinates
   on its own, as before);
3. the crossing speed (``V2XMerging._stream_speed``: the mean of the stage's upstream mainline speeds,
   clipped to [8, v_max], unless the target is given) and the coordination on the stage's rows.

Only the deterministic default is fused: the controller keeps the separate calls for a channel without
delay (its CAMs are sent between the stage and the delivery) and the Python coordinator (a ``SlotCheck``).
"""

from __future__ import annotations

import math
from typing import Any

from numba import njit, types
from numba.core import sigutils

from corridor.controllers.merging.cam_kernel import STATUS_OK, _pose_tick_signature, cam_pose_tick_into
from corridor.controllers.merging.coord_kernel import _COORD_SIG, HAVE_C_POW, coordinate_into
from corridor.vehicles.tracks.node_pool import _DELIVER_SIG, _deliver_fuse_tick, referenced_in_order

NOT_RUN = -1  # a stage the call did not reach (see fused_tick_into)

_DLV_OWN = (*range(17), 18, *range(22, 41))  # _deliver_fuse_tick's arguments the stage does not share
_CRD_OWN = (6, 8, 12, *range(14, 24))  # coordinate_into's arguments the others do not share


def _signature() -> Any:
    cam = _pose_tick_signature()
    dlv_args, dlv_ret = sigutils.normalize_signature(_DELIVER_SIG)
    crd_args, crd_ret = sigutils.normalize_signature(_COORD_SIG)
    i8, f8 = types.int64, types.float64
    args = (*cam.args, *(dlv_args[j] for j in _DLV_OWN), *(crd_args[j] for j in _CRD_OWN), f8[:], i8[:, :], f8, f8)
    return types.Tuple((cam.return_type, dlv_ret, i8, crd_ret, f8))(*args)


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
                    c_si, c_sf, c_cfg, c_cfg_int, c_z_int, c_z_flt, c_slot_out, ref_t, ref_dr, target_given, v_max):  # type: ignore[no-untyped-def]
    """The three stages (see the module docstring), flat: ``cam_pose_tick_into``'s arguments, then those of
    ``_deliver_fuse_tick`` (``d_``) and ``coordinate_into`` (``c_``) that the stage does not share (the
    delivery's listen keys are the stage's ``keys``; the coordination's rows the stage's buffers, its RSU
    tracks the delivery's), ``referenced_in_order``'s outputs (``ref_t``, ``ref_dr``), the target speed
    given [m/s] (NaN: the crossing speed) and ``v_max`` [m/s]. (One flat list: a tuple argument is typed by
    numba's dispatcher in Python, ~50 us a call here, an array or a scalar in C.)

    Returns (the stage's counts, the delivery's (copies, updates, free rows, missing intervals), the
    delivered references, the coordination's (status, zone, slots), the target [m/s]); a stage not reached
    has ``NOT_RUN`` as its first count."""
    r_cam = cam_pose_tick_into(t, ref_xy, back, cos_yaw, sin_yaw, size, front_x, pos, role, uid, conn_of,
                               on_ramp_lane, joins_lane, merged_lane, ramp_code, cos_ramp, dist, connected, ramp,
                               right, merged, speed, row_node, near_lo, near_hi, zone_lo, zone_hi, stream_lo,
                               stream_hi, slot_of, n_vehicle_rx, next_s, period, known, chan_pos, rsu, x_rsu, y_rsu,
                               order_node, depth, fifo, r0, lane, lane_pos, near, src, cam_pos, val, ref, ptr, dst,
                               keys, cand, leader, sp, due, newcomers)
    if r_cam[0] != STATUS_OK:
        return r_cam, (NOT_RUN, 0, 0, 0), 0, (NOT_RUN, 0, 0), math.nan
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
        return r_cam, r_dlv, k_refs, (NOT_RUN, 0, 0), math.nan
    if math.isnan(target_given):  # V2XMerging._stream_speed: np.mean's bits (sum / n), then np.clip's value
        v = stream_sum / n_s if n_s else v_max
        v = 8.0 if 8.0 > v else v  # Python's max(v, 8.0)
        target = v_max if v_max < v else v  # Python's min(v, v_max)
    else:
        target = target_given
    r_crd = coordinate_into(t, cand[:n_c], connected[:n], dist[:n], speed, ramp[:n], c_row_key, row_node, c_rsu_slot,
                            d_row_of, d_x, d_t_row, c_z_noise, target, c_entered_of, c_s_int, c_s_flt, c_si, c_sf,
                            c_cfg, c_cfg_int, c_z_int, c_z_flt, c_slot_out)
    return r_cam, r_dlv, k_refs, r_crd, target
