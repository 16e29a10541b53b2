"""The slew error's scale (chekan.joint.likelihood.transient_amplitude): the net transient
on a monotone slew; the sum of its parts where parts on both sides of the hold's
equilibrium cancel in the net (a slew through level), since late angles misplace each."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from chekan.joint.likelihood import transient_amplitude


def _one_slew(path_pix, e_prev, e_hold, w_prev):
    """One hold after a slew of M samples: the amplitude and the net |y₀ − E|."""
    M = len(path_pix)
    wm = np.full((2, M), (1.0 - w_prev) / M)  # hold 1 is the one read (hold 0 alike)
    Em = np.broadcast_to(np.asarray(path_pix, float)[None, None, :], (2, 2, M))
    E = np.array([[e_prev, e_prev], [e_hold, e_hold]])  # hold 0, then the hold after the slew
    R = np.zeros((2, 2))
    amp = transient_amplitude(
        jnp.asarray(E),
        jnp.full(2, w_prev),
        jnp.asarray(wm),
        jnp.asarray(Em),
        jnp.asarray(R),
    )
    net = abs(w_prev * e_prev + wm[0] @ np.asarray(path_pix, float) - e_hold)
    return float(amp[1, 0]), float(net)


def test_a_monotone_slew_keeps_the_net_transient():
    amp, net = _one_slew([2.0, 4.0, 6.0, 8.0], e_prev=0.0, e_hold=10.0, w_prev=0.2)
    assert np.isclose(amp, net) and net > 1.0


def test_parts_on_both_sides_of_the_hold_add_where_the_net_cancels_them():
    # the previous hold's equilibrium 9.5 pix below this one's, the path through level
    # above it: the net transient cancels them; a path late in time misplaces each part
    path = [-6.0, -1.0, 3.0, 5.0, 4.0]
    amp, net = _one_slew(path, e_prev=-9.5, e_hold=0.0, w_prev=0.3)
    expected = 0.3 * 9.5 + 0.7 * np.mean(np.abs(path))
    assert np.isclose(amp, expected) and np.isclose(net, abs(-0.3 * 9.5 + 0.7 * np.mean(path)))
    assert amp > 2.5 * net
