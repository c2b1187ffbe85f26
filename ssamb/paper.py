"""The paper's reported figures, for the paper-versus-reproduction table.

These are the only numbers typed into ssamb's report: they are quotations of the paper
(section and figure given with each), never results of ours.
"""

#: name -> (value, unit, where in the paper)
PAPER = {
    "fit_x_pct": (93.76, "%", "section 3, Fig. 4: x-axis fit of the nominal closed-loop LTI model"),
    "fit_y_pct": (50.76, "%", "section 3, Fig. 4: y-axis fit of the nominal closed-loop LTI model"),
    "order_plant": (9, "", "section 3: 9th order AMB plant model (4 inputs, 2 outputs)"),
    "order_amplifier": (7, "", "section 3: 7th order power amplifier model (4 inputs, 4 outputs)"),
    "order_selfsensing": (3, "", "section 3: 3rd order SISO self-sensing model"),
    "weight_fit_max_db": (3.0, "dB", "section 5: at most 3 dB between envelope and fitted weight"),
    "mu_scale_for_unity": (0.0012, "", "section 6.2: weight scaled down by 0.0012 to obtain useful results"),
    "mu_peak_hz": (2.0, "Hz", "section 6.2, Fig. 8: the 2 Hz component dominates the mu plot"),
    "delevitation_nonlinear_s": (0.18, "s", "section 6.2, Fig. 9: delevitation just after 0.18 s"),
    "delevitation_nominal_lti_s": (None, "s", "section 6.2, Fig. 9: the nominal LTI model does not delevitate"),
    "delevitation_augmented_lti_s": (None, "s", "section 6.2, Fig. 9: the augmented model does not delevitate"),
    "sweep_amplitude_m": (99e-6, "m", "section 6.2: 99 um frequency sweep"),
    "sweep_band_hz": ((11.0, 50.0), "Hz", "section 6.2: 11 Hz to 50 Hz"),
    "multisine_amplitude_m": (100e-6, "m", "section 5: 100 um random-phase multisine"),
    "multisine_band_hz": ((5.0, 26.0), "Hz", "section 5: 5 Hz to 26 Hz"),
    "fs_hz": (83.3e3, "Hz", "section 3: sampling frequency 83.3 kHz"),
}
