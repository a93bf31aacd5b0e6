//! A run's `metrics.csv` (`run_dir::METRICS_CSV`): opened for the training loop's rows, and read
//! back (the logged training steps and the validations) as the plots and the live viewer draw them.

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};

/// A logged training step of `metrics.csv`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainRow {
    /// The step (0-based, as the CSV names it).
    pub step: u64,
    /// The batch's loss.
    pub loss: f64,
    /// The fine level's PSNR on the batch, in dB.
    pub psnr: f64,
    /// The learning rate.
    pub lr: f64,
}

/// The rows of `metrics.csv` that the curves draw (the plots, the live viewer): the logged
/// training steps and the validations (`val_psnr`). The one reader of the file's columns.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MetricsRows {
    /// Rows with a loss, training PSNR and learning rate.
    pub train: Vec<TrainRow>,
    /// (step, test PSNR per scale) of rows with a validation.
    pub val: Vec<(u64, Vec<f64>)>,
}

impl MetricsRows {
    /// Reads the text of a `metrics.csv` (header first); rows that do not parse are left out.
    #[must_use]
    pub fn parse(text: &str) -> Self {
        let mut m = Self::default();
        for line in text.lines().skip(1) {
            let f: Vec<&str> = line.split(',').collect();
            let Some(step) = f.first().and_then(|s| s.parse::<u64>().ok()) else { continue };
            let num = |i: usize| f.get(i).and_then(|x| x.parse::<f64>().ok());
            if let (Some(loss), Some(psnr), Some(lr)) = (num(1), num(3), num(4)) {
                m.train.push(TrainRow { step, loss, psnr, lr });
            }
            if let Some(v) = f.get(7).and_then(|v| v.split(';').map(str::parse).collect::<Result<Vec<f64>, _>>().ok()) {
                m.val.push((step, v));
            }
        }
        m
    }

    /// Scales of the widest validation row (0 without validation).
    #[must_use]
    pub fn scales(&self) -> usize {
        self.val.iter().map(|(_, v)| v.len()).max().unwrap_or(0)
    }
}

/// Opens `metrics.csv` for appending rows after `from_step` (dropping any rows at or past it
/// that a crash left behind), writing the header for a new file.
pub fn open_csv(path: &Path, from_step: u64) -> Result<std::fs::File> {
    const HEADER: &str = "step,loss,level_losses,psnr,lr,rays_per_s,elapsed_s,val_psnr";
    let kept: Vec<String> = match std::fs::read_to_string(path) {
        Ok(text) => text
            .lines()
            .skip(1)
            .filter(|l| l.split(',').next().and_then(|s| s.parse::<u64>().ok()).is_some_and(|s| s < from_step))
            .map(str::to_string)
            .collect(),
        Err(_) => Vec::new(),
    };
    let mut f = std::fs::File::create(path).with_context(|| format!("writing {}", path.display()))?;
    writeln!(f, "{HEADER}")?;
    for l in kept {
        writeln!(f, "{l}")?;
    }
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::{MetricsRows, TrainRow};

    /// The rows as the training loop writes them: logged steps with and without a validation,
    /// a validation-only row (a run stopped between logs), and a damaged line left out.
    #[test]
    fn metrics_rows_are_read_as_the_training_loop_writes_them() {
        let text = "step,loss,level_losses,psnr,lr,rays_per_s,elapsed_s,val_psnr\n\
                    0,0.25,0.3;0.2,6.02,1e-5,900,1.0,\n\
                    9,0.1,0.1;0.1,10.00,5e-4,950,2.0,12.500;13.250\n\
                    12,,,,,,3.5,14.000;15.000\n\
                    garbage\n";
        let m = MetricsRows::parse(text);
        assert_eq!(
            m.train,
            [
                TrainRow { step: 0, loss: 0.25, psnr: 6.02, lr: 1e-5 },
                TrainRow { step: 9, loss: 0.1, psnr: 10.0, lr: 5e-4 }
            ]
        );
        assert_eq!(m.val, [(9, vec![12.5, 13.25]), (12, vec![14.0, 15.0])]);
        assert_eq!(m.scales(), 2);
    }
}
