use clap::Parser;

fn main() -> std::process::ExitCode {
    exit_on_output_error();
    let cli = metrolog::cli::Cli::parse();
    match metrolog::cli::run(cli) {
        Ok(()) => std::process::ExitCode::from(metrolog::exit::OK),
        Err(e) => {
            // An error quotes its input (a column name, a log's string): no control characters.
            metrolog::cmd::input::print_err(&format!("error: {e:#}"));
            // Distinct codes so that systemd does not restart what a restart cannot cure
            // (see daemon/src/exit.rs and the README's deploy section).
            std::process::ExitCode::from(metrolog::exit::code_for(&e))
        }
    }
}

/// A command whose standard output cannot be written (`> /dev/full`, a closed pipe) ends with
/// one line on stderr and the I/O error code, as a Unix tool would, instead of `println!`'s
/// panic. Every other panic is reported as before.
fn exit_on_output_error() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let msg = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.starts_with("failed printing to stdout") {
            use std::io::Write as _;
            let reason = msg.trim_start_matches("failed printing to stdout: ");
            let _ = writeln!(
                std::io::stderr(),
                "error: cannot write the output: {reason}"
            );
            std::process::exit(i32::from(metrolog::exit::IO_ERROR));
        }
        default(info);
    }));
}
