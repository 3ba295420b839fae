//! The `filmscope` command line: parse, run, print a one-line error, set the exit code.

fn main() -> std::process::ExitCode {
    filmscope::cli::main()
}
