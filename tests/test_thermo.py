"""Equations of state: thermodynamic identities and the parcel-energy derivatives."""

import numpy as np
import pytest

from varint.terms.thermo import IdealGas, Tait

EOS = [IdealGas(1.4, 287.05), Tait(1000.0, 1e5, 2.2e9, 7.15), Tait(1000.0, 1e5, 2.2e9, 1.0)]


@pytest.mark.parametrize("eos", EOS, ids=["ideal", "tait", "tait-linear"])
def test_pressure_is_rho_squared_de_drho(eos):
    rho = np.array([0.8, 1.0, 1.3]) * (1.2 if eos.name == "ideal-gas" else 1000.0)
    S = eos.entropy(1.2, 1e5) if eos.has_entropy else None
    m, V = 1.0, 1.0 / rho
    e = lambda r: eos.psi(m / r, m, S) / m  # noqa: E731
    d = 1e-4 * rho
    de = (e(rho + d) - e(rho - d)) / (2 * d)
    p = eos.pressure(rho, S)
    assert np.allclose(rho ** 2 * de, p, rtol=1e-6, atol=1e-6 * np.abs(p).max())


@pytest.mark.parametrize("eos", EOS, ids=["ideal", "tait", "tait-linear"])
def test_psi_derivatives(eos):
    m = 0.01
    rho0 = 1.2 if eos.name == "ideal-gas" else 1000.0
    V = np.array([0.9, 1.0, 1.1]) * m / rho0
    S = eos.entropy(1.2, 1e5) if eos.has_entropy else None
    d1, d2 = eos.dpsi(V, m, S)
    h = 1e-4 * V
    assert np.allclose(d1, (eos.psi(V + h, m, S) - eos.psi(V - h, m, S)) / (2 * h), rtol=1e-6, atol=1e-6 * np.abs(d1).max())
    d1p, _ = eos.dpsi(V + h, m, S)
    d1m, _ = eos.dpsi(V - h, m, S)
    assert np.allclose(d2, (d1p - d1m) / (2 * h), rtol=1e-6, atol=1e-6 * np.abs(d2).max())


def test_sound_speeds():
    gas = IdealGas(1.4, 287.05)
    S = gas.entropy(1.225, 101325.0)
    assert gas.sound_speed(1.225, S) == pytest.approx(np.sqrt(1.4 * 101325 / 1.225))
    water = Tait(1000.0, 1e5, 2.2e9, 7.15)
    assert water.sound_speed(1000.0) == pytest.approx(np.sqrt(2.2e9 / 1000.0))
    assert water.density(water.pressure(1003.0)) == pytest.approx(1003.0)
