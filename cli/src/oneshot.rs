//! One-shot gRPC client commands (`jsae health`, `jsae recommend`, `jsae submit-sessions`):
//! an address as users type it, and a current-thread runtime that prints the answer on
//! stdout and the reason on stderr.

use std::fmt::Display;
use std::future::Future;
use std::process::ExitCode;

/// `host:port` or a full `http://host:port` URL, as a URL.
pub fn url(addr: &str) -> String {
    if addr.contains("://") {
        addr.to_owned()
    } else {
        format!("http://{addr}")
    }
}

/// Runs `call` to completion: exit 0 with its answer on stdout, 1 with `name: reason` on
/// stderr.
pub fn run<T: Display>(name: &str, call: impl Future<Output = Result<T, String>>) -> ExitCode {
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(r) => r,
        Err(e) => {
            eprintln!("{name}: {e}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(call) {
        Ok(answer) => {
            println!("{answer}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("{name}: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn bare_addresses_get_a_scheme() {
        assert_eq!(super::url("127.0.0.1:1"), "http://127.0.0.1:1");
        assert_eq!(super::url("http://h:2"), "http://h:2");
    }
}
