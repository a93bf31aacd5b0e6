//! `mipnerf view`: the live viewer of a run in the browser.

use std::path::PathBuf;

use anyhow::Result;

use crate::backend::DeviceArgs;
use crate::config::Backend;
use crate::session::Session;

/// The flags of `mipnerf view`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The run directory (a finished run, or one that is training).
    #[arg(long, value_name = "RUN_DIR")]
    pub run: PathBuf,
    /// The port (0: any free one).
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// The address to listen on; anything but a loopback address lets other machines in.
    #[arg(long, default_value = "127.0.0.1")]
    pub host: String,
    /// Where frames are rendered: cpu, gpu or auto.
    #[arg(long, value_enum, default_value_t = Backend::Cpu)]
    pub backend: Backend,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// Serves the viewer until interrupted.
///
/// # Errors
/// An unreadable run, a port in use, or no device.
pub fn run(a: Args, session: &Session) -> Result<()> {
    let (session, device) = (session.clone(), a.device.options());
    let args = crate::view::ViewArgs {
        run: a.run,
        host: a.host,
        port: a.port,
        backend: a.backend,
        share: None,
        device,
        session,
    };
    crate::view::serve(&args)
}
