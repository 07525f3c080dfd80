"""The output spectrum of a held track input against the white one (tenth session).

The filter's model takes the track velocities as continuous white noise (Van Loan). The
paper's literal eqs. (6)-(7) hold them constant over each 1 ms sample and feed them
through the zero-order-hold Gamma (``firmware_sim.truth``, ``track_input="held"``, each
held value of variance q fs). This prints, per band, the ratio of the five sensors'
noise-free output power under the held input to that under the white input, at the
paper's Sec. 4.2 vehicle, 42.5 m/s, 1 kHz, from the exact transfer of the discrete model
(no simulation), and each band's share of the white input's power::

    python docs/data/scripts/track_input_spectrum_2026-11-29.py
"""

import numpy as np

from gateway.model import vehicle as vm

FS_HZ, V_MPS = 1000.0, 42.5
A = vm.system_matrix(vm.VehicleParams(), vm.THETA_SEC42, V_MPS)
G = vm.input_matrix()
q = vm.track_intensity(vm.AR_PAPER_DEFAULT, V_MPS)
d = vm.discretize(A, G, q, 1 / FS_HZ)
H = vm.output_matrix(A, vm.SENSORS_5)
q_held = q * FS_HZ * d.gamma @ d.gamma.T
f_hz = np.linspace(0.01, 500, 50_000)
eye = np.eye(len(A))
white, held = [], []
for fk in f_hz:
    T = H @ np.linalg.inv(np.exp(2j * np.pi * fk / FS_HZ) * eye - d.phi)
    white.append(np.real(np.einsum("ij,jk,ik->i", T, d.qd, T.conj())))
    held.append(np.real(np.einsum("ij,jk,ik->i", T, q_held, T.conj())))
white_a, held_a = np.array(white), np.array(held)
print("sensors:", vm.SENSORS_5)
for lo, hi in [(0, 5), (5, 20), (20, 50), (50, 150), (150, 500), (0, 500)]:
    m = (f_hz >= lo) & (f_hz < hi)
    print(f"{lo}-{hi} Hz: held / white power {np.round(held_a[m].sum(0) / white_a[m].sum(0), 4)}"
          f", share of the white power {np.round(white_a[m].sum(0) / white_a.sum(0), 3)}")
