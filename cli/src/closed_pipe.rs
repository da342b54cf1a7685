//! A command whose standard output is closed under it (`jsae eval --run X | head -4`) ends
//! quietly with success, as Unix tools do, instead of panicking with a backtrace. Rust ignores
//! SIGPIPE, so a print to a closed pipe panics ("failed printing to stdout: Broken pipe");
//! [`run`] keeps that panic's message out of the output and turns it into a clean exit,
//! after the unwinding has run every destructor (a `jsae train` whose output is closed still
//! stops its service processes).

use std::any::Any;
use std::panic::UnwindSafe;
use std::process::ExitCode;

/// Whether a panic's payload is a print to a closed standard output or error.
fn is_closed_pipe(payload: &(dyn Any + Send)) -> bool {
    let text = payload
        .downcast_ref::<String>()
        .map(String::as_str)
        .or_else(|| payload.downcast_ref::<&str>().copied());
    text.is_some_and(|t| t.starts_with("failed printing to std") && t.contains("Broken pipe"))
}

/// Runs `command`; a print to a closed pipe inside it ends it with success and no message.
/// Any other panic is reported and goes on as before.
pub fn run(command: impl FnOnce() -> ExitCode + UnwindSafe) -> ExitCode {
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !is_closed_pipe(info.payload()) {
            report(info);
        }
    }));
    match std::panic::catch_unwind(command) {
        Ok(code) => code,
        Err(payload) if is_closed_pipe(&*payload) => ExitCode::SUCCESS,
        Err(payload) => std::panic::resume_unwind(payload),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_print_to_a_closed_pipe_counts() {
        let closed: Box<dyn Any + Send> =
            Box::new("failed printing to stdout: Broken pipe (os error 32)".to_string());
        assert!(is_closed_pipe(&*closed));
        let other: Box<dyn Any + Send> = Box::new("index out of bounds");
        assert!(!is_closed_pipe(&*other));
        assert_eq!(run(|| ExitCode::from(3)), ExitCode::from(3));
    }
}
