//! What every command-line tool of cabletrack shares (`vision`, `trainer`, `mesh-bench`, `monitor`,
//! `supervisor` and the services): standard output that stops quietly when its reader goes away, and
//! one way to end with an error.
//!
//! Rust ignores SIGPIPE, so writing to a pipe whose reader has exited (`vision detect DIR | head -3`)
//! fails with [`io::ErrorKind::BrokenPipe`], and `println!` panics on it. A tool writes its output
//! with [`outln!`], passes the error up with `?` like any other, and ends through [`fail`]: a reader
//! that went away is not a failure, the tool has nothing left to do and exits with status 0, without
//! a word; any other error is reported once, with its chain, and the exit status is 1.

use std::error::Error;
use std::fmt;
use std::io::{self, Write};
use std::process::ExitCode;

/// Writes `args` and a newline to standard output; an error of kind `BrokenPipe` when the reader
/// has gone (see [`reader_gone`]).
pub fn write_line(args: fmt::Arguments<'_>) -> io::Result<()> {
    let mut out = io::stdout().lock();
    out.write_fmt(args)?;
    // Standard output is line-buffered: the newline sends the line, and a closed pipe shows here.
    out.write_all(b"\n")
}

/// `println!` that returns the write's `io::Result` instead of panicking: `outln!("{x}")?`.
#[macro_export]
macro_rules! outln {
    () => {
        $crate::write_line(::std::format_args!(""))
    };
    ($($arg:tt)*) => {
        $crate::write_line(::std::format_args!($($arg)*))
    };
}

/// Whether `err`, or an error in its chain of sources, is a write to a pipe whose reader has gone.
pub fn reader_gone(err: &(dyn Error + 'static)) -> bool {
    let mut next = Some(err);
    while let Some(e) = next {
        if e.downcast_ref::<io::Error>()
            .is_some_and(|io| io.kind() == io::ErrorKind::BrokenPipe)
        {
            return true;
        }
        next = e.source();
    }
    false
}

/// `err` and its sources joined by ": ", a source left out when the text before already says it.
pub fn chain(err: &(dyn Error + 'static)) -> String {
    let mut text = err.to_string();
    let mut next = err.source();
    while let Some(cause) = next {
        let said = cause.to_string();
        if !text.contains(&said) {
            text.push_str(": ");
            text.push_str(&said);
        }
        next = cause.source();
    }
    text
}

/// How `tool` ends on `err`: its reader gone, quietly with success; otherwise `TOOL: error: CHAIN`
/// on standard error and failure. Writing the report never panics, not even with standard error
/// closed.
pub fn fail(tool: &str, err: &(dyn Error + 'static)) -> ExitCode {
    if reader_gone(err) {
        return ExitCode::SUCCESS;
    }
    let _ = writeln!(io::stderr(), "{tool}: error: {}", chain(err));
    ExitCode::FAILURE
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Wrapped(&'static str, io::Error);

    impl fmt::Display for Wrapped {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str(self.0)
        }
    }

    impl Error for Wrapped {
        fn source(&self) -> Option<&(dyn Error + 'static)> {
            Some(&self.1)
        }
    }

    fn broken_pipe() -> io::Error {
        io::Error::from(io::ErrorKind::BrokenPipe)
    }

    #[test]
    fn a_broken_pipe_anywhere_in_the_chain_is_the_reader_gone() {
        assert!(reader_gone(&broken_pipe()));
        assert!(reader_gone(&Wrapped("printing the table", broken_pipe())));
        let boxed: Box<dyn Error> = Box::new(broken_pipe());
        assert!(reader_gone(boxed.as_ref()));
    }

    #[test]
    fn other_errors_are_not_the_reader_gone() {
        let missing = io::Error::from(io::ErrorKind::NotFound);
        assert!(!reader_gone(&Wrapped("reading config/x.toml", missing)));
        assert!(!reader_gone(&fmt::Error));
    }

    #[test]
    fn the_chain_names_each_cause_once() {
        let e = Wrapped("reading config/x.toml", io::Error::other("no such file"));
        assert_eq!(chain(&e), "reading config/x.toml: no such file");
        let said = Wrapped(
            "reading config/x.toml: no such file",
            io::Error::other("no such file"),
        );
        assert_eq!(chain(&said), "reading config/x.toml: no such file");
    }

    #[test]
    fn a_closed_pipe_ends_with_success_and_another_error_with_failure() {
        assert_eq!(fail("tool", &broken_pipe()), ExitCode::SUCCESS);
        let other = io::Error::from(io::ErrorKind::NotFound);
        assert_eq!(fail("tool", &other), ExitCode::FAILURE);
    }
}
