//! `--init auto`: one fit from each of several starts (a plane, a sphere, a
//! reconstruction's depth map), each in its own folder `OUTDIR/start-NAME/` with its own
//! checkpoint, and the one [`choose_start`] keeps, its outputs copied to `OUTDIR`. With a
//! single start (any other `--init`) the fit writes into `OUTDIR` itself.

use super::run::{fit, FitConfig, FitReport, Init};
use crate::error::{Error, Result};
use crate::scene::Scene;
use optim::checkpoint::write_atomic;
use optim::fit::Progress;
use std::path::{Path, PathBuf};

/// One start of an `--init auto` fit.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StartSummary {
    pub init: String,
    pub final_loss: f64,
    pub relative_l2: f64,
    pub seconds: f64,
}

/// `--init auto` fits from a plane, a sphere and a reconstruction's depth map (the LCT's,
/// confocal; the backprojection's, otherwise), in that order, and keeps the lowest final
/// loss, except that a start later in the order wins when its loss is within this
/// fraction of the lowest: the reconstruction's start is itself a reconstruction of the
/// data, a sphere is the shape of a closed object, and losses this close are both at the
/// data's noise (docs/BASELINES.md: on the tilted plate with Poisson noise the plane's
/// and the LCT's differ by 0.03 %, and the LCT start's surface is 2.8x closer to the
/// truth; where another start wins, it wins by 6-15 %).
pub const AUTO_LOSS_MARGIN: f64 = 0.01;

/// Index of the start `--init auto` keeps among final losses in the order the starts
/// ran (module rule above: the last start within [`AUTO_LOSS_MARGIN`] of the lowest).
fn choose_start(losses: &[f64]) -> usize {
    let lowest = losses.iter().cloned().fold(f64::INFINITY, f64::min);
    losses
        .iter()
        .rposition(|&l| l * (1.0 - AUTO_LOSS_MARGIN) <= lowest)
        .unwrap_or(0)
}

/// `OUTDIR/start-NAME`: where `--init auto` fits from start `NAME`.
pub fn start_dir(output: &Path, name: &str) -> PathBuf {
    output.join(format!("start-{name}"))
}

/// Copies the chosen start's outputs into `out` (atomically); their new paths.
fn copy_outputs(files: &[PathBuf], out: &Path) -> Result<Vec<PathBuf>> {
    files
        .iter()
        .map(|f| {
            let to = out.join(f.file_name().unwrap_or_default());
            crate::io::text::check_regular(f, "a start's output")?;
            let bytes = std::fs::read(f).map_err(|e| Error::io(f, e))?;
            write_atomic(&to, &bytes).map_err(|e| Error::io(&to, e))?;
            Ok(to)
        })
        .collect()
}

/// Where and how [`fit_starts`] runs.
pub struct StartsRun<'a> {
    pub output: &'a Path,
    /// Several starts, each in `start-NAME/`, a failing one left out; else one, in `output`.
    pub auto: bool,
    pub resume: bool,
    /// The option's name as the front end spells it, for the notes.
    pub flag: &'a str,
}

/// What [`fit_starts`] kept.
pub struct AutoFit {
    pub name: String,
    pub report: FitReport,
    /// Every start that ran, in order (empty unless `auto`).
    pub starts: Vec<StartSummary>,
    /// The starts that failed, each `NAME: error`.
    pub failed: Vec<String>,
}

/// Fits from each of `starts` (`cfg.init` and `cfg.resume` set per start) and keeps one.
pub fn fit_starts(
    scene: &Scene,
    measured: &[f32],
    cfg: &mut FitConfig,
    starts: Vec<(&str, Init)>,
    run: &StartsRun,
    progress: Progress,
    log: &mut dyn FnMut(&str),
) -> Result<AutoFit> {
    let (auto, flag) = (run.auto, run.flag);
    let mut fits = Vec::new();
    let mut failed = Vec::new();
    for (name, init) in starts {
        let dir = if auto {
            start_dir(run.output, name)
        } else {
            run.output.to_path_buf()
        };
        cfg.init = init;
        // A start an interrupted `auto` fit never reached has no checkpoint: it starts.
        cfg.resume = run.resume && dir.join("checkpoint").join("stage.bin").exists();
        if auto {
            log(&format!(
                "{flag} auto: fitting from the {name} start ({})",
                dir.display()
            ));
        }
        match fit(scene, measured, cfg, &dir, progress.clone()) {
            Ok(report) => fits.push((name, report)),
            // One start of several failing (a step thrown out of the scene, a start the
            // reconstruction cannot make) leaves the others: said, not fatal.
            Err(e) if auto && !matches!(e, Error::Cancelled) => {
                log(&format!(
                    "{flag} auto: the {name} start failed, left out: {e}"
                ));
                failed.push((name, e));
            }
            Err(e) => return Err(e),
        }
    }
    if fits.is_empty() {
        return Err(failed.swap_remove(0).1);
    }
    let summaries: Vec<StartSummary> = fits
        .iter()
        .map(|(name, r)| StartSummary {
            init: name.to_string(),
            final_loss: r.final_loss,
            relative_l2: r.relative_l2,
            seconds: r.seconds,
        })
        .collect();
    let chosen = choose_start(&fits.iter().map(|(_, r)| r.final_loss).collect::<Vec<_>>());
    let (name, mut report) = fits.swap_remove(chosen);
    if auto {
        report.files = copy_outputs(&report.files, run.output)?;
        report.seconds = summaries.iter().map(|s| s.seconds).sum();
        log(&format!(
            "{flag} auto: kept the {name} start ({})",
            summaries
                .iter()
                .map(|s| format!("{}: relative L2 {:.4}", s.init, s.relative_l2))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    Ok(AutoFit {
        name: name.to_string(),
        report,
        starts: if auto { summaries } else { Vec::new() },
        failed: failed.iter().map(|(n, e)| format!("{n}: {e}")).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_keeps_the_lowest_loss_or_a_later_start_within_the_margin() {
        assert_eq!(choose_start(&[0.0228943, 0.0229015]), 1); // a tie: the later one
        assert_eq!(choose_start(&[0.0290, 0.0288]), 1);
        assert_eq!(choose_start(&[0.0175, 0.0196]), 0); // 11 % lower: the plane's
        assert_eq!(choose_start(&[0.5]), 0); // one start
                                             // plane, sphere, reconstruction: the lowest, unless a later one is within 1 %
        assert_eq!(choose_start(&[0.0139, 0.0097, 0.0150]), 1);
        assert_eq!(choose_start(&[0.0139, 0.0097, 0.00975]), 2);
        assert_eq!(choose_start(&[0.0100, 0.0200, 0.0300]), 0);
        assert_eq!(choose_start(&[0.0100, 0.01005, 0.0300]), 1);
    }
}
