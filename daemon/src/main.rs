use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = metrolog::cli::Cli::parse();
    match metrolog::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
