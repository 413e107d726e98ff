use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = metrolog::cli::Cli::parse();
    match metrolog::cli::run(cli) {
        Ok(()) => std::process::ExitCode::from(metrolog::exit::OK),
        Err(e) => {
            eprintln!("error: {e:#}");
            // Distinct codes so that systemd does not restart what a restart cannot cure
            // (see daemon/src/exit.rs and the README's deploy section).
            std::process::ExitCode::from(metrolog::exit::code_for(&e))
        }
    }
}
