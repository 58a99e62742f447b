"""Shared by the in-motion tests: feeding a simulated run to a MotionAligner."""


def fed_in_blocks(al, r, block: int, velocities: bool = True):
    """Give ``al`` the run ``r``'s GNSS velocities (all ahead, at their stamps; unless
    ``velocities`` is False), then its IMU samples in blocks of ``block``; yield the truth
    index after each block (the state is then that of ``r.C[j]``'s instant)."""
    if velocities:
        for tg, vg in zip(r.gnss_t, r.gnss_v):
            al.add_velocity(tg, vg)
    n = len(r.gyro)
    for k in range(0, n, block):
        al.update(r.t[k + 1:k + 1 + block], r.gyro[k:k + block], r.accel[k:k + block])
        yield min(k + block, n)
