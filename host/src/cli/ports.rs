//! `gonio ports`: the serial ports of this machine, instruments marked.
use std::process::ExitCode;

/// Arguments of `gonio ports`.
#[derive(clap::Args)]
pub struct Args {}

/// Run `gonio ports`.
pub fn run(_args: Args) -> anyhow::Result<ExitCode> {
    let ports = host::instrument::serial::list_ports()?;
    if ports.is_empty() {
        println!(
            "no serial ports found (with no instrument attached, `gonio measure --sim SAMPLE` uses the simulated one)"
        );
    }
    for port in ports {
        let usb = port
            .usb_id
            .map(|(vid, pid)| format!("{vid:04x}:{pid:04x}"))
            .unwrap_or_else(|| "-".into());
        let mark = if port.is_instrument {
            "gonio instrument"
        } else {
            ""
        };
        println!(
            "{:<24} {:<10} {:<28} {}",
            port.path,
            usb,
            port.product.unwrap_or_default(),
            mark
        );
    }
    Ok(ExitCode::SUCCESS)
}
