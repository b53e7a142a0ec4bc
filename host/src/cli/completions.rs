//! `gonio completions SHELL`: the shell's completion script for every subcommand and
//! option, generated from gonio's own command line (clap_complete), to standard output.
use std::process::ExitCode;

/// Arguments of `gonio completions`.
#[derive(clap::Args)]
pub struct Args {
    /// The shell: bash, zsh, fish, elvish or powershell. Bash: `gonio completions bash >
    /// ~/.local/share/bash-completion/completions/gonio`.
    #[arg(value_enum)]
    pub shell: clap_complete::Shell,
}

/// Print the completions of `command` (the whole `gonio` command line) for the shell.
pub fn run(args: Args, command: &mut clap::Command) -> anyhow::Result<ExitCode> {
    clap_complete::generate(args.shell, command, "gonio", &mut std::io::stdout());
    Ok(ExitCode::SUCCESS)
}
