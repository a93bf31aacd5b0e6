//! The checks of training settings: every number before anything is allocated, and the settings
//! a run would ignore (for its data's format, or without the occupancy grid).

use anyhow::{Result, bail};
use mipnerf_data::Format;

use super::{Backend, MAX_BATCH_RAYS, MAX_STEPS, RayShape, TrainSettings};

impl TrainSettings {
    /// The Tri-Mip settings: the planes' only with a Tri-Mip field, the MLP's and the learning
    /// rate's with a grid field (Tri-Mip or hash grid), each within what the grid and the MLP can
    /// be built with. They are config-file keys, without flags.
    pub(super) fn check_tri_mip(&self) -> Result<()> {
        let planes =
            [("tri_mip_resolution", self.tri_mip_resolution.is_some()), ("tri_mip_tv", self.tri_mip_tv.is_some())];
        let grid = [
            ("tri_mip_mlp", self.tri_mip_mlp.is_some()),
            ("tri_mip_lr_mult", self.tri_mip_lr_mult.is_some()),
            ("grid_adam_eps", self.grid_adam_eps.is_some()),
            ("grid_adam_skip_untouched", self.grid_adam_skip_untouched.is_some()),
            ("coarse_to_fine_steps", self.coarse_to_fine_steps.is_some_and(|n| n != 0)),
        ];
        if !self.uses_tri_mip()
            && let Some((key, _)) = planes.iter().find(|(_, on)| *on)
        {
            bail!("`{key}` (a config-file key) sets the Tri-Mip field's planes: add --field tri-mip, or drop it");
        }
        if self.field != Some(super::FieldArg::HashGrid) && self.hash_grid_decay.is_some() {
            bail!(
                "`hash_grid_decay` (a config-file key) sets the hash grid's weight decay: add --field hash-grid, or drop it"
            );
        }
        if !self.uses_grid_field() {
            if let Some((key, _)) = grid.iter().find(|(_, on)| *on) {
                bail!(
                    "`{key}` (a config-file key) sets a grid field's MLP, optimiser or schedule: add --field tri-mip or \
                     hash-grid, or drop it"
                );
            }
            return Ok(());
        }
        if let Some(r) = self.tri_mip_resolution
            && !(r.is_power_of_two() && (16..=2048).contains(&r))
        {
            bail!("`tri_mip_resolution` must be a power of two from 16 to 2048 (texels a side), got {r}");
        }
        if let Some(mlp @ [depth, width, depth_condition, width_condition]) = self.tri_mip_mlp
            && !((1..=16).contains(&depth)
                && (1..=16).contains(&depth_condition)
                && (1..=1024).contains(&width)
                && (1..=1024).contains(&width_condition))
        {
            bail!(
                "`tri_mip_mlp` is [trunk depth, trunk width, colour depth, colour width], depths 1 to 16 and widths 1 \
                 to 1024, got {mlp:?}"
            );
        }
        if let Some(m) = self.tri_mip_lr_mult
            && !(m.is_finite() && m > 0.0 && m <= 1000.0)
        {
            bail!("`tri_mip_lr_mult` must be a positive number up to 1000, got {m}");
        }
        if let Some(e) = self.grid_adam_eps
            && !(e.is_finite() && e > 0.0 && e <= 1.0)
        {
            bail!("`grid_adam_eps` must be a positive number up to 1 (Instant-NGP's 1e-15), got {e}");
        }
        if let Some(w) = self.tri_mip_tv
            && !(w.is_finite() && (0.0..=1000.0).contains(&w))
        {
            bail!("`tri_mip_tv` must be a number from 0 (off) to 1000, got {w}");
        }
        if let Some(w) = self.hash_grid_decay
            && !(w.is_finite() && (0.0..=1000.0).contains(&w))
        {
            bail!("`hash_grid_decay` must be a number from 0 (off) to 1000, got {w}");
        }
        Ok(())
    }

    /// Checks every number of resolved settings before anything is allocated: counts positive
    /// and within what the run can address (`u32` step and ray counters), rates and thresholds
    /// finite. `bytes_per_ray` is the memory one ray of a batch needs, for the error message.
    ///
    /// # Errors
    /// The first bad value, named as the flag and as the config-file key.
    pub fn validate(&self, bytes_per_ray: u64) -> Result<()> {
        let name = |key: &str| format!("--{} (`{key}` in a config file)", key.replace('_', "-"));
        let positive = [
            ("steps", self.steps.unwrap_or(1)),
            ("checkpoint_every", self.checkpoint_every.unwrap_or(1)),
            ("log_every", self.log_every.unwrap_or(1)),
        ];
        for (key, v) in positive {
            if v == 0 {
                bail!("{} must be at least 1, got 0", name(key));
            }
        }
        let steps = self.steps.unwrap_or(1);
        if steps > MAX_STEPS {
            bail!(
                "{} must be at most {MAX_STEPS} (the step counter of the random numbers is 32-bit), got {steps}",
                name("steps")
            );
        }
        let batch = self.batch_rays.unwrap_or(1024);
        let need = |rays: u64| rays.saturating_mul(bytes_per_ray) as f64 / f64::from(1u32 << 30);
        if batch == 0 || batch > MAX_BATCH_RAYS {
            bail!(
                "{} must be between 1 and {MAX_BATCH_RAYS}, got {batch} (it would need about {:.1} GiB for one batch's \
                 buffers; the paper uses 4096)",
                name("batch_rays"),
                need(batch as u64)
            );
        }
        self.time_budget_seconds()?;
        self.snapshot_seconds()?;
        if let Some(b) = self.occupancy_bound
            && !(b.is_finite() && b > 0.0)
        {
            bail!("{} must be a positive number, got {b}", name("occupancy_bound"));
        }
        self.check_tri_mip()?;
        if self.lr_decay_steps == Some(0) {
            bail!("`lr_decay_steps` (a config-file key) must be at least 1, got 0");
        }
        if self.density_noise_steps.is_some_and(|n| n > 0) && self.density_noise.unwrap_or(0.0) == 0.0 {
            bail!(
                "`density_noise_steps` (a config-file key) fades the density noise, which is 0 here: set \
                 --density-noise, or drop it"
            );
        }
        if let Some(b) = self.adam_beta2
            && !(b.is_finite() && b > 0.0 && b < 1.0)
        {
            bail!(
                "`adam_beta2` (a config-file key) must be a number between 0 and 1 (flax's 0.999; Instant-NGP's 0.99), \
                 got {b}"
            );
        }
        if let Some(w) = self.mlp_l2
            && !(w.is_finite() && (0.0..=1.0).contains(&w))
        {
            bail!("`mlp_l2` (a config-file key) must be a number from 0 (off) to 1 (Instant-NGP's 1e-6), got {w}");
        }
        if let Some(r) = self.spherify_radius
            && !(r.is_finite() && r > 0.0)
        {
            bail!("{} must be a positive number, got {r}", name("spherify_radius"));
        }
        if let Some(r) = self.occupancy_resolution
            && !(2..=256).contains(&r)
        {
            bail!("{} must be between 2 and 256, got {r}", name("occupancy_resolution"));
        }
        if self.unbounded == Some(true) {
            if self.occupancy_bound.is_some() {
                bail!(
                    "--occupancy-bound does not apply to an unbounded scene, whose grid covers all of its contracted \
                     space (the cube of half side 2): drop it"
                );
            }
            if self.spherify == Some(false) {
                bail!("an unbounded scene is spherified (its cameras in the unit ball): drop spherify = false");
            }
            if self.spherify_radius.is_some() {
                bail!(
                    "--spherify-radius does not apply to an unbounded scene, whose farthest camera lies on the unit \
                     sphere: drop it"
                );
            }
            if self.ray_shape == Some(RayShape::Cylinder) {
                bail!(
                    "an unbounded scene casts cones (cylinders are for forward-facing scenes in NDC): drop --ray-shape"
                );
            }
        }
        if self.distortion_loss.is_some_and(|d| d != 0.0) && self.backend == Some(Backend::Gpu) {
            bail!("the distortion loss (--distortion-loss) runs on the CPU backend only: use --backend cpu");
        }
        if self.occupancy == Some(true) && self.supersample.unwrap_or(1) > 1 {
            bail!(
                "occupancy-guided sampling ({}) does not guide supersampled pixels: drop --supersample",
                if self.preset == Some(super::PresetArg::Fast) {
                    "the fast preset's; --no-occupancy turns it off"
                } else {
                    "--occupancy"
                }
            );
        }
        if let Some(images) = self.val_images
            && !(1..=1000).contains(&images)
        {
            bail!("{} must be between 1 and 1000, got {images}", name("val_images"));
        }
        for (key, v) in [("grad_max_norm", self.grad_max_norm), ("grad_max_val", self.grad_max_val)] {
            if let Some(v) = v
                && !(v.is_finite() && v >= 0.0)
            {
                bail!("{} must be a finite number >= 0 (0 = off), got {v}", name(key));
            }
        }
        Ok(())
    }

    /// Refuses settings that the data's format would ignore: `--llff-factor`, `--spherify` and
    /// `--spherify-radius` on Blender scenes (which have no `images_N/` and no poses to
    /// spherify), `--half-res` on anything but a Blender scene (photos downscale with
    /// `--llff-factor`; multiscale data has its scales already). For settings as given (before
    /// [`resolved`](Self::resolved) fills them in), on a new run.
    ///
    /// # Errors
    /// The settings given, named as flags, with the one the format uses instead.
    pub fn check_format_settings(&self, format: Format) -> Result<()> {
        let photo_flags = given(&[
            (self.llff_factor.is_some(), "--llff-factor"),
            (self.spherify == Some(true), "--spherify"),
            (self.spherify_radius.is_some(), "--spherify-radius"),
        ]);
        if !format.is_photos() && !photo_flags.is_empty() {
            bail!(
                "{} {} for photos (LLFF or COLMAP data), and this dataset is {}: drop {}{}",
                photo_flags.join(" and "),
                if photo_flags.len() > 1 { "are" } else { "is" },
                if format == Format::Blender { "a Blender scene" } else { "a multiscale Blender scene" },
                if photo_flags.len() > 1 { "them" } else { "it" },
                if format == Format::Blender && self.llff_factor.is_some() {
                    " (--half-res loads a Blender scene at half resolution; `mipnerf convert --size N` makes smaller \
                     copies)"
                } else {
                    ""
                }
            );
        }
        if self.half_res == Some(true) && format != Format::Blender {
            bail!(
                "--half-res is for Blender scenes (transforms_*.json), and this dataset is {}: drop it{}",
                match format {
                    Format::Multiscale => "a multiscale scene, whose four scales are made already",
                    _ => "photos",
                },
                if format.is_photos() { " and pick the image folder with --llff-factor N (images_N/)" } else { "" }
            );
        }
        Ok(())
    }

    /// Refuses the occupancy grid's settings (`--occupancy-resolution`, `--occupancy-bound`,
    /// `--no-occupancy-masks`) for a run without occupancy-guided sampling, where they would do
    /// nothing. For settings as given (before [`resolved`](Self::resolved) drops them).
    ///
    /// # Errors
    /// The settings given, named as flags, and the way to use them.
    pub fn check_occupancy_settings(&self) -> Result<()> {
        let occupancy = self.uses_occupancy();
        let given = given(&[
            (self.occupancy_resolution.is_some(), "--occupancy-resolution"),
            (self.occupancy_bound.is_some(), "--occupancy-bound"),
            (self.occupancy_masks.is_some(), "--no-occupancy-masks"),
        ]);
        if !occupancy && !given.is_empty() {
            bail!(
                "{} set(s) the occupancy grid, which this run does not use: add --occupancy (the fast preset has it), \
                 or drop {}",
                given.join(" and "),
                if given.len() > 1 { "them" } else { "it" }
            );
        }
        Ok(())
    }
}

/// The flags of `flags` that were given (`true`), in order.
fn given(flags: &[(bool, &'static str)]) -> Vec<&'static str> {
    flags.iter().filter_map(|&(set, flag)| set.then_some(flag)).collect()
}
