"""Numba kernel of the fractional integrators' partial fractions (:mod:`.oustaloup`).

A population optimiser draws a new order ``alpha`` for nearly every FOLQI candidate, so each
candidate builds two filters. Their residues are products of differences, which numpy forms
with a dozen small array operations (about 10 us); here they are one compiled loop that takes
each product in index order, as ``numpy.prod`` along a row does
(``tests/objectives/qtp/test_oustaloup.py`` compares them on every order the configs allow,
within the rounding of the products' factors: 1e-13 relative). The zeros and poles themselves
stay numpy's: its ``power`` is not libm's ``pow`` in the last bit for about one argument in
twenty, and a compiled ``**`` is libm's.
"""

from numba import njit


@njit(cache=True)
def partial_fraction_residues(poles, zeros, gain, out):
    """``out[k] = gain prod_j (p_k - z_j) / prod_{i != k} (p_k - p_i)``.

    Parameters
    ----------
    poles : (n,) float64 ndarray
        Distinct real poles.
    zeros : (m,) float64 ndarray
    gain : float
    out : (n,) float64 ndarray
        The residues (written).
    """
    n = poles.size
    for k in range(n):
        pk = poles[k]
        num = 1.0
        for j in range(zeros.size):
            num *= pk - zeros[j]
        den = 1.0
        for i in range(n):
            if i != k:
                den *= pk - poles[i]
        out[k] = (gain * num) / den
