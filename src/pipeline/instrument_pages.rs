//! The pages of the instrument commands on the twin: `measure --instrument
//! ball-sensor|probe` (ISO 10791-6 ranges, the trace, the location terms identified with
//! σ) and the hexapod's `ballbar` and `calibrate` (ISO 230-4; the parameters with σ, the
//! gauge, the pose errors before and after). Built on [`super::pages`]' page parts; made
//! on request, written by the caller.

use crate::math::Real;
use crate::report::html::render_page;
use crate::report::pages as page;

/// A term's value or σ in its unit: µrad for tilts, µm for offsets.
fn term_text(name: &str, v: Real, signed: bool) -> String {
    let (k, unit) = if super::is_angle_term(name) {
        (1e6, "µrad")
    } else {
        (1e3, "µm")
    };
    if signed {
        format!("{:+.4} {unit}", v * k)
    } else {
        format!("{:.4} {unit}", v * k)
    }
}

/// `measure --instrument ball-sensor | probe`'s page: ISO 10791-6's deviation ranges per
/// sweep and the trace, the identified location terms with σ, what is not determined, the
/// singular values; `summary` is what the CLI prints.
pub fn rotary_page(out: &super::rotary::RotaryOutcome, summary: &str) -> String {
    use crate::report::html::{Plot, Section};
    let rep = &out.report;
    let mut sections = vec![Section {
        heading: "ISO 10791-6 deviation ranges".into(),
        intro: format!(
            "{} measurements with the {}: per sweep, the range (max − min) of each coordinate of the ball's deviation from the table-side point, and its largest distance from it (µm).",
            rep.samples, rep.instrument
        ),
        columns: [
            "sweep",
            "axis",
            "from (°)",
            "to (°)",
            "samples",
            "X",
            "Y",
            "Z",
            "max distance",
        ]
        .map(String::from)
        .to_vec(),
        rows: rep
            .sweeps
            .iter()
            .map(|f| {
                vec![
                    f.sweep.to_string(),
                    f.axis.to_string(),
                    format!("{}", f.range_deg[0]),
                    format!("{}", f.range_deg[1]),
                    f.samples.to_string(),
                    format!("{:.4}", f.deviation_range_mm[0] * 1e3),
                    format!("{:.4}", f.deviation_range_mm[1] * 1e3),
                    format!("{:.4}", f.deviation_range_mm[2] * 1e3),
                    format!("{:.4}", f.max_distance_mm * 1e3),
                ]
            })
            .collect(),
    }];
    let mut plots = Vec::new();
    match crate::report::svg::rotary_trace_svg(
        &out.samples,
        &format!("ISO 10791-6 {}: {}", rep.instrument, rep.scene),
    ) {
        Ok(svg) => plots.push(Plot {
            caption: "The deviation of the ball from the table-side point, X red, Y blue, Z green (µm), measurement by measurement.".into(),
            svg,
        }),
        Err(e) => plots.push(Plot {
            caption: format!("The deviation trace is not drawn: {e}."),
            svg: String::new(),
        }),
    }
    if let Some(id) = &rep.identification {
        let rows = |ts: &[super::TermReport]| -> Vec<Vec<String>> {
            ts.iter()
                .map(|t| {
                    vec![
                        t.name.clone(),
                        term_text(&t.name, t.value, true),
                        term_text(&t.name, t.sigma, false),
                        t.injected
                            .map_or_else(|| "—".into(), |v| term_text(&t.name, v, true)),
                    ]
                })
                .collect()
        };
        let cols = ["term", "value", "σ", "injected by the scene"]
            .map(String::from)
            .to_vec();
        sections.push(Section {
            heading: "Identified location terms".into(),
            intro: format!(
                "Solved for {}; each identified term with its standard uncertainty σ (offsets µm, tilts µrad).",
                id.terms.join(", ")
            ),
            columns: cols.clone(),
            rows: rows(&id.identified),
        });
        if !id.combinations.is_empty() {
            sections.push(Section {
                heading: "Determined combinations".into(),
                intro: "Combinations the test determines though their members are not determined alone.".into(),
                columns: cols,
                rows: rows(&id.combinations),
            });
        }
        sections.extend(page::list_section(
            "Not determined",
            "Directions the test does not determine, held at the model's values: a table-side point cannot see them.",
            &id.not_determined,
        ));
        sections.extend(page::list_section(
            "No data",
            "Terms no measurement depends on: add sweeps of their axis.",
            &id.no_data,
        ));
        let threshold = 1.0 / crate::calibration::calibrate::DETERMINED_FRACTION;
        let mut sv = page::singular_value_rows(&id.singular_values, threshold);
        sv.push(page::margin_row(&id.margin));
        sv.push(vec![
            "χ²".into(),
            format!("{:.6e}", id.chi2),
            format!("{} degrees of freedom", id.dof),
        ]);
        sections.push(Section {
            heading: "Identifiability".into(),
            intro: format!("Singular values of the Jacobian scaled by each term's realistic magnitude and whitened by the measurements' σ; a direction is determined from {threshold}."),
            columns: vec!["#".into(), "singular value".into(), "".into()],
            rows: sv,
        });
        let p = id.fixed_point_mm;
        let sp = id.fixed_point_sigma_mm;
        sections.push(Section {
            heading: "Table-side point".into(),
            intro: "Where the identification puts the sensor's measuring point or the sphere's centre (workpiece frame), estimated with the terms.".into(),
            columns: vec!["coordinate".into(), "mm".into(), "σ (mm)".into()],
            rows: ["x", "y", "z"]
                .iter()
                .enumerate()
                .map(|(k, c)| vec![(*c).into(), format!("{:+.6}", p[k]), format!("{:.3e}", sp[k])])
                .collect(),
        });
        sections.push(page::fit_section(&id.fit));
        plots.extend(page::spectrum_plot(
            &id.singular_values,
            Some(threshold),
            "Singular values of the scaled Jacobian: dark bars are determined directions, light ones are not.",
        ));
    }
    render_page(&page::instrument_page(
        format!(
            "twinmill measure --instrument {}: {}",
            rep.instrument, rep.scene
        ),
        summary.into(),
        sections,
        plots,
        page::json(rep),
    ))
}

/// `twinmill ballbar`'s page: the hexapod's circle as ISO 230-4 evaluates it.
pub fn hexapod_ballbar_page(scene: &str, o: &super::dbb::BallbarOutcome) -> String {
    render_page(&page::circular_page(
        &format!("twinmill ballbar: {scene}"),
        &o.summary,
        &o.samples,
        &o.figures,
        &format!("ISO 230-4: {scene}"),
        page::json(o),
    ))
}

/// The sections every hexapod calibration page opens with: identifiability, fit, what is
/// not determined, what is weak.
fn identification_sections(
    c: &crate::calibration::hexapod_calibrate::HexapodCalibration,
) -> Vec<crate::report::html::Section> {
    use crate::report::html::Section;
    let id = &c.identifiability;
    let mut sections = vec![Section {
        heading: "Identifiability".into(),
        intro: format!(
            "{} unknowns ({} parameters{}); a direction of the parameters is determined when its σ is below a tenth of its realistic magnitude (singular value ≥ {}, the balls' coordinates projected out).",
            id.unknowns,
            id.unknowns - id.ball_unknowns,
            if id.ball_unknowns > 0 {
                format!(" and {} table-ball coordinates", id.ball_unknowns)
            } else {
                String::new()
            },
            id.margin.cut
        ),
        columns: vec!["figure".into(), "value".into()],
        rows: vec![
            vec!["rank".into(), id.rank.to_string()],
            vec!["rank margin".into(), id.margin.describe()],
            vec![
                "parameters determined".into(),
                format!("{} of 24", id.parameters_determined),
            ],
            vec![
                "condition number (determined)".into(),
                format!("{:.6e}", id.condition_number),
            ],
            vec![
                "undetermined outside the gauge".into(),
                format!("{:.3e}", id.undetermined_outside_gauge),
            ],
            vec![
                "residual rms (µm)".into(),
                format!("{:.4}", c.residual_rms_mm * 1e3),
            ],
            vec![
                "σ of a reading (µm)".into(),
                format!("{:.4}", c.sigma_mm * 1e3),
            ],
            vec!["Levenberg–Marquardt steps".into(), c.iterations.to_string()],
        ],
    }];
    sections.push(page::fit_section(&c.fit));
    if id.gauge.is_empty() {
        sections.push(Section {
            heading: "Not determined".into(),
            intro: "Nothing: the plate's balls are known, so they fix the table frame and every parameter is determined.".into(),
            columns: Vec::new(),
            rows: Vec::new(),
        });
    } else {
        sections.extend(page::list_section(
            "Not determined (the gauge)",
            "The ball bar measures lengths only: moving the base frame rigidly together with the table balls changes no reading, so its six rigid motions are not determined. The base joints are reported with their rigid motion removed (best fit to nominal).",
            &id.gauge,
        ));
    }
    sections.extend(page::list_section(
        "Weakly determined",
        "Directions outside the gauge the readings see with σ above a tenth of their magnitude (held at nominal, never valued), and those near that cut.",
        &id.weak,
    ));
    sections
}

/// The singular-value table and the threshold (the rank cut) of a hexapod calibration.
fn singular_value_section(
    c: &crate::calibration::hexapod_calibrate::HexapodCalibration,
) -> (crate::report::html::Section, Real) {
    use crate::report::html::Section;
    let id = &c.identifiability;
    let threshold = id.margin.cut;
    let section = Section {
        heading: "Singular values".into(),
        intro: "Of the scaled, whitened Jacobian, largest first.".into(),
        columns: vec!["#".into(), "singular value".into(), "".into()],
        rows: id
            .singular_values
            .iter()
            .enumerate()
            .map(|(i, s)| {
                vec![
                    (i + 1).to_string(),
                    format!("{s:.6e}"),
                    if i < id.rank {
                        "determined"
                    } else {
                        "not determined"
                    }
                    .into(),
                ]
            })
            .collect(),
    };
    (section, threshold)
}

/// `twinmill calibrate`'s page: the identified parameters with σ beside the injected
/// ones, the singular values, what the readings do not determine and why (the gauge), the
/// pose errors before and after, the working times and the trials.
pub fn calibrate_page(scene: &str, o: &super::dbb::CalibrateOutcome) -> String {
    use crate::report::html::Section;
    let c = &o.run.calibration;
    let id = &c.identifiability;
    let mut sections = identification_sections(c);
    sections.push(Section {
        heading: "Identified parameters".into(),
        intro: "Each parameter's deviation from nominal, identified with its standard uncertainty σ, beside the deviation the scene injects (in the same gauge).".into(),
        columns: ["parameter", "injected (mm)", "identified (mm)", "σ (µm)", "|identified − injected| / σ"]
            .map(String::from)
            .to_vec(),
        rows: o
            .run
            .parameters
            .iter()
            .map(|p| {
                vec![
                    p.name.clone(),
                    format!("{:+.6}", p.injected_mm),
                    format!("{:+.6}", p.identified_mm),
                    format!("{:.4}", p.sigma_mm * 1e3),
                    format!("{:.2}", (p.identified_mm - p.injected_mm).abs() / p.sigma_mm),
                ]
            })
            .collect(),
    });
    let (sv, threshold) = singular_value_section(c);
    sections.push(sv);
    let mut pose = vec![
        vec![
            "largest level positioning error (mm)".into(),
            format!("{:.6}", o.run.before.position_mm),
            format!("{:.6}", o.run.after.position_mm),
        ],
        vec![
            "largest pivot error (mm)".into(),
            format!("{:.6}", o.run.before.pivot_mm),
            format!("{:.6}", o.run.after.pivot_mm),
        ],
    ];
    if let Some((rot, tr)) = o.run.table_alignment {
        pose.push(vec![
            "table calibration corrects".into(),
            format!("{rot:.2} µrad"),
            format!("{tr:.6} mm"),
        ]);
    }
    sections.push(Section {
        heading: "Before and after".into(),
        intro: "Pose errors of the machine driven by the nominal controller (before) and by the calibrated one (after).".into(),
        columns: vec!["figure".into(), "before".into(), "after".into()],
        rows: pose,
    });
    sections.push(Section {
        heading: "Working time".into(),
        intro: "Both procedures' circles, readings and time.".into(),
        columns: [
            "procedure",
            "circles",
            "readings",
            "path (mm)",
            "set-up (min)",
            "measuring (min)",
            "total (min)",
        ]
        .map(String::from)
        .to_vec(),
        rows: o
            .work
            .iter()
            .map(|w| {
                vec![
                    w.procedure.name().to_string(),
                    w.circles.to_string(),
                    w.readings.to_string(),
                    format!("{:.0}", w.path_mm),
                    format!("{:.1}", w.setup_min),
                    format!("{:.1}", w.measuring_min),
                    format!("{:.1}", w.total_min),
                ]
            })
            .collect(),
    });
    if let Some(t) = &o.trials {
        sections.push(Section {
            heading: "Trials".into(),
            intro: format!("{} seeded trials of random deviations.", t.trials),
            columns: vec!["figure".into(), "value".into()],
            rows: vec![
                vec![
                    "parameters within 3σ".into(),
                    format!("{:.1} %", 100.0 * t.within_3_sigma),
                ],
                vec![
                    "trials all within 3σ".into(),
                    format!("{:.1} %", 100.0 * t.trials_all_within_3_sigma),
                ],
                vec![
                    "worst before: position / pivot (mm)".into(),
                    format!("{:.6} / {:.6}", t.before_position_mm, t.before_pivot_mm),
                ],
                vec![
                    "worst after: position / pivot (mm)".into(),
                    format!("{:.6} / {:.6}", t.after_position_mm, t.after_pivot_mm),
                ],
            ],
        });
    }
    let plots = page::spectrum_plot(
        &id.singular_values,
        (threshold > 0.0).then_some(threshold),
        "Singular values of the calibration's Jacobian: dark bars are determined directions; the gauge's lie below the line.",
    )
    .into_iter()
    .collect();
    render_page(&page::instrument_page(
        format!("twinmill calibrate: {scene} ({})", o.procedure.name()),
        o.summary.clone(),
        sections,
        plots,
        page::json(o),
    ))
}

/// `identify --readings`' page (a calibration from traces measured on the machine): the
/// identifiability, the fit, the identified parameters with σ (no truth to compare with),
/// the singular values, the error the calibration removes (the controller that ran the
/// circles on the identified machine) and the controller file it writes.
pub fn measured_calibrate_page(scene: &str, o: &super::dbb::MeasuredCalibrationOutcome) -> String {
    use crate::report::html::Section;
    let c = &o.calibration;
    let id = &c.identifiability;
    let mut sections = identification_sections(c);
    sections.push(Section {
        heading: "Identified parameters".into(),
        intro: "Each parameter's deviation from nominal, identified with its standard uncertainty σ (jig-free: in the report's gauge, the base joints' rigid motion removed).".into(),
        columns: ["parameter", "identified (mm)", "σ (µm)"]
            .map(String::from)
            .to_vec(),
        rows: c
            .estimates
            .iter()
            .map(|e| {
                vec![
                    e.name.clone(),
                    format!("{:+.6}", e.value_mm),
                    format!("{:.4}", e.sigma_mm * 1e3),
                ]
            })
            .collect(),
    });
    let (sv, threshold) = singular_value_section(c);
    sections.push(sv);
    sections.push(Section {
        heading: "The correction".into(),
        intro: "How far the controller that ran the circles puts the tool from where it is commanded on the identified machine: the error the calibrated controller removes, if the identified machine is the real one.".into(),
        columns: vec!["figure".into(), "value (mm)".into()],
        rows: vec![
            vec![
                "largest level positioning error".into(),
                format!("{:.6}", o.predicted_correction.position_mm),
            ],
            vec![
                "largest pivot error".into(),
                format!("{:.6}", o.predicted_correction.pivot_mm),
            ],
        ],
    });
    sections.push(Section {
        heading: "Files read".into(),
        intro: "One trace per circle of the plan, in its order.".into(),
        columns: vec!["circle".into(), "file".into()],
        rows: o
            .files
            .iter()
            .enumerate()
            .map(|(k, f)| vec![(k + 1).to_string(), f.clone()])
            .collect(),
    });
    let plots = page::spectrum_plot(
        &id.singular_values,
        (threshold > 0.0).then_some(threshold),
        "Singular values of the calibration's Jacobian: dark bars are determined directions; the gauge's lie below the line.",
    )
    .into_iter()
    .collect();
    render_page(&page::instrument_page(
        format!(
            "twinmill identify --readings: {scene} ({})",
            o.procedure.name()
        ),
        o.summary.clone(),
        sections,
        plots,
        page::json(o),
    ))
}
