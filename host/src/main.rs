fn main() -> std::process::ExitCode {
    maobi::cli::main()
}
