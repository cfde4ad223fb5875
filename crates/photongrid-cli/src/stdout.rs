//! Results printed on standard output. A reader that stops early (`photongrid compare … | head`)
//! closes the pipe: that ends the command quietly and successfully, as it does for other
//! command-line tools, instead of the panic `println!` gives.

use std::fmt;
use std::io::{self, Write};

/// Writes `args` to standard output; a closed pipe exits with status 0, another write error
/// with status 1 and a message.
pub fn write(args: fmt::Arguments) {
    let mut out = io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|()| out.flush()) {
        if e.kind() == io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("error: cannot write to standard output: {e}");
        std::process::exit(1);
    }
}

/// `println!` that ends quietly when standard output's reader has gone ([`write`]).
#[macro_export]
macro_rules! outln {
    () => { $crate::stdout::write(format_args!("\n")) };
    ($($arg:tt)*) => { $crate::stdout::write(format_args!("{}\n", format_args!($($arg)*))) };
}

/// `print!` that ends quietly when standard output's reader has gone ([`write`]).
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => { $crate::stdout::write(format_args!($($arg)*)) };
}
