//! `handeye config`: the configuration's own documentation.

use std::process::ExitCode;

/// `handeye config …`.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    #[command(subcommand)]
    command: ConfigCommand,
}

#[derive(Debug, clap::Subcommand)]
enum ConfigCommand {
    /// Print every configuration key with its type, unit, default and range, as the book's
    /// page (`handeye config reference > docs/src/config-reference.md`).
    Reference,
}

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    match args.command {
        ConfigCommand::Reference => print!("{}", handeye::config::reference::markdown()),
    }
    Ok(ExitCode::SUCCESS)
}
