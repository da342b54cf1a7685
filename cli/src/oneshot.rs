//! One-shot gRPC client commands (`jsae health`, `jsae recommend`, `jsae submit-sessions`):
//! an address as users type it, and a current-thread runtime that prints the answer on
//! stdout and the reason on stderr.

use std::fmt::Display;
use std::future::Future;
use std::process::ExitCode;

use jsae_net::security::{Connection, Security};

/// `host:port` or a full `http://host:port` URL, as a URL (`https://` for a bare address
/// where `security` trusts a CA).
pub fn url(addr: &str, security: &Security) -> String {
    if addr.contains("://") {
        addr.to_owned()
    } else {
        format!("{}://{addr}", security.scheme())
    }
}

/// A connection to `addr` as users type it, with `security`'s TLS and token; the URL beside
/// it for messages.
pub fn connect(addr: &str, security: &Security) -> Result<(Connection, String), String> {
    let url = url(addr, security);
    let channel = security.channel(&url).map_err(|e| e.to_string())?;
    Ok((channel, url))
}

/// A refused or failed call as a one-line reason.
pub fn reason(url: &str, status: &tonic::Status) -> String {
    format!("{url}: {}", jsae_net::status_reason(status))
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
    fn a_reason_names_every_cause() {
        let inner = std::io::Error::new(std::io::ErrorKind::ConnectionRefused, "refused");
        let outer = std::io::Error::other(inner);
        assert_eq!(jsae_net::error_chain(&outer), "refused");
        #[derive(Debug)]
        struct Top(std::io::Error);
        impl std::fmt::Display for Top {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("transport error")
            }
        }
        impl std::error::Error for Top {
            fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
                Some(&self.0)
            }
        }
        let top = Top(std::io::Error::new(
            std::io::ErrorKind::ConnectionRefused,
            "Connection refused",
        ));
        assert_eq!(
            jsae_net::error_chain(&top),
            "transport error: Connection refused"
        );
    }

    #[test]
    fn bare_addresses_get_a_scheme() {
        let plain = jsae_net::security::Security::default();
        assert_eq!(super::url("127.0.0.1:1", &plain), "http://127.0.0.1:1");
        assert_eq!(super::url("http://h:2", &plain), "http://h:2");
    }
}
