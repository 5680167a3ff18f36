//! Progress bars for long work: drawn on a terminal, hidden when stderr is a file or a pipe (logs stay clean).

use std::io::IsTerminal;

/// A bar of `len` steps with an indicatif `template`.
pub fn bar(len: u64, template: &str) -> indicatif::ProgressBar {
    let bar = if std::io::stderr().is_terminal() {
        indicatif::ProgressBar::new(len)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(template).unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}
