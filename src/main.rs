//! The `filmscope` command line: parse, run, print a one-line error, set the exit code.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
