//! A bad network, packet by packet, with netem's settings and rules (`tc qdisc ... netem`): loss,
//! delay with jitter, reordering, a rate cap and a queue limit. The demo applies it with `tc netem`
//! where the kernel has it; a kernel without `sch_netem` gets the same rules from this core, run
//! by `shore-link impair` between two TUN devices (see `main.rs`).
//!
//! The rules, as netem applies them to each packet offered at `now`:
//! - **loss P% [C%]**: dropped when a correlated uniform draw falls at or below P.
//! - **limit N**: dropped when N packets are already waiting (netem's default, 1000).
//! - **delay D [J]**: sent at `now + D + u`, `u` uniform in `[-J, J]`; the queue is ordered by send
//!   time, so jitter larger than the gap between two packets reorders them.
//! - **reorder P% [C%]** (with a delay): P% of the packets (correlated draws) are sent at once, the
//!   others delayed, so the immediate ones overtake those waiting.
//! - **rate R**: packets leave one after another, each taking `len x 8 / R` after the later of its
//!   own delayed time and the previous packet's departure.
//!
//! Correlation is netem's: the draw is `(1 - C) x fresh + C x previous draw`.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::fmt;
use std::str::FromStr;

/// The demo's named settings (`--netem NAME`); anything else is taken as netem's own arguments.
pub const PRESETS: [(&str, &str); 4] = [
    ("loss", "loss 5%"),
    ("delay", "delay 300ms 50ms"),
    ("reorder", "delay 100ms reorder 25% 50%"),
    ("rate", "rate 256kbit"),
];

/// The netem arguments of `setting`: a preset's, or `setting` itself.
pub fn netem_args(setting: &str) -> &str {
    PRESETS
        .iter()
        .find(|(name, _)| *name == setting)
        .map_or(setting, |(_, args)| args)
}

/// netem's default queue limit (packets).
pub const DEFAULT_LIMIT: usize = 1000;

/// One direction's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Probability, 0 to 1, and its correlation.
    pub loss: f64,
    pub loss_correlation: f64,
    pub delay_ns: u64,
    pub jitter_ns: u64,
    pub reorder: f64,
    pub reorder_correlation: f64,
    /// Bits per second; `None`: no cap.
    pub rate_bps: Option<u64>,
    pub limit: usize,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            loss: 0.0,
            loss_correlation: 0.0,
            delay_ns: 0,
            jitter_ns: 0,
            reorder: 0.0,
            reorder_correlation: 0.0,
            rate_bps: None,
            limit: DEFAULT_LIMIT,
        }
    }
}

/// A netem argument that cannot be read, with the argument.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BadSetting(pub String);

impl fmt::Display for BadSetting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BadSetting {}

fn percent(word: &str) -> Result<f64, BadSetting> {
    word.strip_suffix('%')
        .and_then(|n| n.parse::<f64>().ok())
        .filter(|p| (0.0..=100.0).contains(p))
        .map(|p| p / 100.0)
        .ok_or_else(|| BadSetting(format!("`{word}` is not a percentage (e.g. 5%)")))
}

fn time_ns(word: &str) -> Result<u64, BadSetting> {
    let split = word
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(word.len());
    let (n, unit) = word.split_at(split);
    let scale = match unit {
        "s" | "sec" => 1e9,
        "ms" | "msec" => 1e6,
        "us" | "usec" => 1e3,
        "ns" | "nsec" => 1.0,
        _ => return Err(BadSetting(format!("`{word}`: a time needs s, ms or us"))),
    };
    n.parse::<f64>()
        .ok()
        .filter(|v| *v >= 0.0)
        .map(|v| (v * scale).round() as u64)
        .ok_or_else(|| BadSetting(format!("`{word}` is not a time (e.g. 300ms)")))
}

fn rate_bps(word: &str) -> Result<u64, BadSetting> {
    let split = word
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(word.len());
    let (n, unit) = word.split_at(split);
    // tc's units: bit-based with k = 1000, and `bps` meaning bytes per second.
    let scale = match unit.to_ascii_lowercase().as_str() {
        "bit" => 1.0,
        "kbit" => 1e3,
        "mbit" => 1e6,
        "gbit" => 1e9,
        "bps" => 8.0,
        "kbps" => 8e3,
        "mbps" => 8e6,
        _ => {
            return Err(BadSetting(format!(
                "`{word}`: a rate needs bit, kbit, mbit or bps"
            )));
        }
    };
    n.parse::<f64>()
        .ok()
        .map(|v| (v * scale).round() as u64)
        .filter(|v| *v > 0)
        .ok_or_else(|| BadSetting(format!("`{word}` is not a rate (e.g. 256kbit)")))
}

impl FromStr for Settings {
    type Err = BadSetting;

    /// netem's arguments, e.g. `delay 300ms 50ms loss 5% rate 256kbit`.
    fn from_str(s: &str) -> Result<Self, BadSetting> {
        let words: Vec<&str> = s.split_whitespace().collect();
        let mut out = Settings::default();
        let mut i = 0;
        // The optional words after a keyword: those that read as the expected kind.
        let optional = |i: usize, ok: &dyn Fn(&str) -> bool| words.get(i).filter(|w| ok(w));
        while i < words.len() {
            let word = words[i];
            let arg = words
                .get(i + 1)
                .copied()
                .ok_or_else(|| BadSetting(format!("`{word}` needs a value")));
            match word {
                "loss" => {
                    // netem also takes `loss random P%`.
                    let skip = usize::from(words.get(i + 1) == Some(&"random"));
                    let value = words
                        .get(i + 1 + skip)
                        .ok_or_else(|| BadSetting("`loss` needs a percentage".into()))?;
                    out.loss = percent(value)?;
                    i += 2 + skip;
                    if let Some(c) = optional(i, &|w| percent(w).is_ok()) {
                        out.loss_correlation = percent(c)?;
                        i += 1;
                    }
                }
                "delay" => {
                    out.delay_ns = time_ns(arg?)?;
                    i += 2;
                    if let Some(j) = optional(i, &|w| time_ns(w).is_ok()) {
                        out.jitter_ns = time_ns(j)?;
                        i += 1;
                        // A delay's correlation is read and not modelled (uniform jitter alone).
                        if optional(i, &|w| percent(w).is_ok()).is_some() {
                            i += 1;
                        }
                    }
                }
                "reorder" => {
                    out.reorder = percent(arg?)?;
                    i += 2;
                    if let Some(c) = optional(i, &|w| percent(w).is_ok()) {
                        out.reorder_correlation = percent(c)?;
                        i += 1;
                    }
                }
                "rate" => {
                    out.rate_bps = Some(rate_bps(arg?)?);
                    i += 2;
                }
                "limit" => {
                    let a = arg?;
                    out.limit =
                        a.parse().ok().filter(|n| *n > 0).ok_or_else(|| {
                            BadSetting(format!("limit `{a}` is not a packet count"))
                        })?;
                    i += 2;
                }
                other => {
                    return Err(BadSetting(format!(
                        "`{other}` in `{s}`: known are loss, delay, reorder, rate, limit"
                    )));
                }
            }
        }
        if out.reorder > 0.0 && out.delay_ns == 0 {
            return Err(BadSetting(format!(
                "`{s}`: reorder needs a delay (the packets not reordered are delayed)"
            )));
        }
        if out.jitter_ns > out.delay_ns {
            return Err(BadSetting(format!(
                "`{s}`: a jitter larger than the delay would send packets before they came"
            )));
        }
        Ok(out)
    }
}

/// SplitMix64: a small, seedable generator; every draw of the emulator comes from it.
#[derive(Clone, Debug)]
pub struct Draws(u64);

impl Draws {
    pub fn new(seed: u64) -> Self {
        Draws(seed)
    }

    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A correlated draw: `(1 - c) x fresh + c x previous`.
#[derive(Clone, Copy, Debug, Default)]
struct Correlated {
    last: f64,
}

impl Correlated {
    fn draw(&mut self, draws: &mut Draws, correlation: f64) -> f64 {
        let fresh = draws.uniform();
        let value = (1.0 - correlation) * fresh + correlation * self.last;
        self.last = value;
        value
    }
}

/// What became of an offered packet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fate {
    /// Waiting, to leave at this time (ns).
    Queued {
        at_ns: u64,
    },
    Lost,
    /// The queue was full.
    Overflow,
}

/// Counts of one direction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    pub offered: u64,
    pub lost: u64,
    pub overflow: u64,
    /// Sent at once by `reorder`, ahead of the delayed packets.
    pub reordered: u64,
    pub sent: u64,
}

/// One direction of the bad network: packets `P` in, the same packets out at their time.
#[derive(Debug)]
pub struct Impairment<P> {
    settings: Settings,
    draws: Draws,
    loss: Correlated,
    reorder: Correlated,
    /// By send time, then arrival order.
    queue: BinaryHeap<Reverse<(u64, u64, Held<P>)>>,
    /// Send time of the packet that leaves last (the rate's serialisation follows it).
    last_departure_ns: Option<u64>,
    arrivals: u64,
    pub counts: Counts,
}

/// A queued packet; ordered by the key alone.
#[derive(Debug)]
struct Held<P>(P);

impl<P> PartialEq for Held<P> {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}
impl<P> Eq for Held<P> {}
impl<P> PartialOrd for Held<P> {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl<P> Ord for Held<P> {
    fn cmp(&self, _: &Self) -> std::cmp::Ordering {
        std::cmp::Ordering::Equal
    }
}

impl<P> Impairment<P> {
    pub fn new(settings: Settings, seed: u64) -> Self {
        Impairment {
            settings,
            draws: Draws::new(seed),
            loss: Correlated::default(),
            reorder: Correlated::default(),
            queue: BinaryHeap::new(),
            last_departure_ns: None,
            arrivals: 0,
            counts: Counts::default(),
        }
    }

    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Packets waiting.
    pub fn waiting(&self) -> usize {
        self.queue.len()
    }

    /// Offers `packet` of `len` bytes at `now_ns`.
    pub fn offer(&mut self, now_ns: u64, packet: P, len: usize) -> Fate {
        let s = self.settings;
        self.counts.offered += 1;
        if s.loss > 0.0 && self.loss.draw(&mut self.draws, s.loss_correlation) <= s.loss {
            self.counts.lost += 1;
            return Fate::Lost;
        }
        if self.queue.len() >= s.limit {
            self.counts.overflow += 1;
            return Fate::Overflow;
        }
        let at_once = s.reorder > 0.0
            && self.reorder.draw(&mut self.draws, s.reorder_correlation) <= s.reorder;
        let mut delay = if at_once {
            self.counts.reordered += 1;
            0
        } else {
            let jitter = if s.jitter_ns > 0 {
                ((2.0 * self.draws.uniform() - 1.0) * s.jitter_ns as f64) as i64
            } else {
                0
            };
            (s.delay_ns as i64 + jitter).max(0) as u64
        };
        let mut start = now_ns;
        if let Some(bps) = s.rate_bps {
            // Serialised behind the packet leaving last; what is left of its own delay still counts.
            if let Some(last) = self.last_departure_ns.filter(|&l| l > now_ns) {
                delay = delay.saturating_sub(last - now_ns);
                start = last;
            }
            delay += (len as u64 * 8 * 1_000_000_000).div_ceil(bps);
        }
        let at_ns = start + delay;
        if s.rate_bps.is_some() {
            self.last_departure_ns = Some(at_ns);
        }
        self.arrivals += 1;
        self.queue
            .push(Reverse((at_ns, self.arrivals, Held(packet))));
        Fate::Queued { at_ns }
    }

    /// When the next packet leaves (ns).
    pub fn next_departure(&self) -> Option<u64> {
        self.queue.peek().map(|Reverse((at, _, _))| *at)
    }

    /// The next packet due at `now_ns`, if any.
    pub fn pop_due(&mut self, now_ns: u64) -> Option<P> {
        if self.next_departure()? > now_ns {
            return None;
        }
        self.counts.sent += 1;
        self.queue.pop().map(|Reverse((_, _, Held(p)))| p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn settings(s: &str) -> Settings {
        s.parse().unwrap()
    }

    /// `n` packets of `len` bytes, one every `every_ns`, each released as soon as due; returns each
    /// packet's (index, departure) in the order they left, and the counts.
    fn run(s: &str, n: u64, every_ns: u64, len: usize, seed: u64) -> (Vec<(u64, u64)>, Counts) {
        let mut imp = Impairment::new(settings(s), seed);
        let mut out = Vec::new();
        let mut fates = Vec::new();
        for i in 0..n {
            let now = i * every_ns;
            while let Some(t) = imp.next_departure().filter(|&t| t <= now) {
                out.push((imp.pop_due(t).unwrap(), t));
            }
            fates.push(imp.offer(now, i, len));
        }
        while let Some(t) = imp.next_departure() {
            out.push((imp.pop_due(t).unwrap(), t));
        }
        (out, imp.counts)
    }

    #[test]
    fn presets_and_netem_arguments_are_read() {
        assert_eq!(netem_args("loss"), "loss 5%");
        assert_eq!(netem_args("delay 10ms"), "delay 10ms");
        for (_, args) in PRESETS {
            args.parse::<Settings>().unwrap();
        }
        let s = settings("delay 300ms 50ms loss 5% 25% rate 256kbit limit 50");
        assert_eq!((s.delay_ns, s.jitter_ns), (300 * MS, 50 * MS));
        assert_eq!((s.loss, s.loss_correlation), (0.05, 0.25));
        assert_eq!((s.rate_bps, s.limit), (Some(256_000), 50));
        let r = settings("delay 100ms reorder 25% 50%");
        assert_eq!((r.reorder, r.reorder_correlation), (0.25, 0.5));
        assert_eq!(settings("loss random 1%").loss, 0.01);
        assert_eq!(settings("rate 1mbit").rate_bps, Some(1_000_000));
        assert_eq!(settings("rate 32kbps").rate_bps, Some(256_000));
        for (bad, says) in [
            ("loss 5", "`5` is not a percentage"),
            ("delay", "`delay` needs a value"),
            ("delay 3 parsecs", "`3`: a time needs"),
            ("rate fast", "`fast`"),
            ("reorder 25%", "reorder needs a delay"),
            ("delay 10ms 20ms", "jitter larger"),
            ("duplicate 1%", "`duplicate`"),
            ("loss 120%", "`120%`"),
        ] {
            let e = bad.parse::<Settings>().unwrap_err().0;
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn loss_drops_its_share() {
        let n = 200_000;
        let (out, counts) = run("loss 5%", n, MS, 100, 7);
        let p = 0.05;
        let sigma = (p * (1.0 - p) / n as f64).sqrt();
        let share = counts.lost as f64 / n as f64;
        // Five binomial standard deviations: a generator or rule off by a tenth of the rate fails.
        assert!((share - p).abs() < 5.0 * sigma, "lost {share}");
        assert_eq!(out.len() as u64 + counts.lost, n);
        // Without delay, the survivors leave as they came, in order.
        assert!(out.windows(2).all(|w| w[0].0 < w[1].0));
    }

    #[test]
    fn jitter_spreads_the_delay_and_reorders_close_packets() {
        let (out, counts) = run("delay 300ms 50ms", 20_000, 10 * MS, 100, 3);
        assert_eq!(counts.lost + counts.overflow, 0);
        let delays: Vec<u64> = out.iter().map(|&(i, t)| t - i * 10 * MS).collect();
        assert!(delays.iter().all(|d| (250 * MS..=350 * MS).contains(d)));
        let mean = delays.iter().sum::<u64>() as f64 / delays.len() as f64;
        // Uniform over 100 ms: the mean's standard deviation is 28.9 / sqrt(20,000) = 0.2 ms.
        assert!((mean / MS as f64 - 300.0).abs() < 1.0, "mean {mean}");
        let below = delays.iter().filter(|&&d| d < 275 * MS).count() as f64 / 20_000.0;
        assert!((below - 0.25).abs() < 0.02, "quarter below 275 ms: {below}");
        // Packets 10 ms apart with +-50 ms of jitter overtake each other.
        let overtaken = out.windows(2).filter(|w| w[0].0 > w[1].0).count();
        assert!(overtaken > 1000, "{overtaken}");
    }

    #[test]
    fn reorder_sends_its_share_at_once_ahead_of_the_delayed() {
        let n = 100_000;
        let (out, counts) = run("delay 100ms reorder 25%", n, MS, 100, 11);
        let p = 0.25;
        let sigma = (p * (1.0 - p) / n as f64).sqrt();
        let share = counts.reordered as f64 / n as f64;
        assert!((share - p).abs() < 5.0 * sigma, "reordered {share}");
        let immediate = out.iter().filter(|&&(i, t)| t == i * MS).count() as u64;
        let delayed = out.iter().filter(|&&(i, t)| t == i * MS + 100 * MS).count() as u64;
        assert_eq!((immediate, immediate + delayed), (counts.reordered, n));
        assert!(out.windows(2).any(|w| w[0].0 > w[1].0));
        // Correlation makes a packet sent at once more likely after one sent at once.
        let mut imp = Impairment::new(settings("delay 100ms reorder 25% 50%"), 5);
        let at_once: Vec<bool> = (0..n)
            .map(|i| imp.offer(i * MS, i, 100) == Fate::Queued { at_ns: i * MS })
            .collect();
        let pairs = at_once.windows(2).filter(|w| w[0]).count() as f64;
        let both = at_once.windows(2).filter(|w| w[0] && w[1]).count() as f64;
        let base = at_once.iter().filter(|&&b| b).count() as f64 / n as f64;
        assert!(
            both / pairs > base + 0.05,
            "{} against {base}",
            both / pairs
        );
    }

    #[test]
    fn a_rate_cap_serialises_packets_at_the_rate() {
        // 100 packets of 1,000 bytes at once through 256 kbit/s: one per 31.25 ms.
        let mut imp = Impairment::new(settings("rate 256kbit"), 1);
        for i in 0..100u64 {
            imp.offer(0, i, 1000);
        }
        let mut last = 0;
        for i in 0..100u64 {
            let t = imp.next_departure().unwrap();
            assert_eq!(t, (i + 1) * 31_250_000);
            assert_eq!(imp.pop_due(t), Some(i));
            last = t;
        }
        assert_eq!(last, 3_125_000_000);
        // A packet after a pause leaves after its own transmission time only.
        assert_eq!(
            imp.offer(10_000_000_000, 100, 100),
            Fate::Queued {
                at_ns: 10_003_125_000
            }
        );
        // Delay and rate: serialised behind the previous packet, the delay already spent counted.
        let mut both = Impairment::new(settings("delay 100ms rate 256kbit"), 1);
        assert_eq!(both.offer(0, 0, 1000), Fate::Queued { at_ns: 131_250_000 });
        assert_eq!(both.offer(0, 1, 1000), Fate::Queued { at_ns: 162_500_000 });
    }

    #[test]
    fn a_full_queue_drops_the_newcomer() {
        let mut imp = Impairment::new(settings("delay 1s limit 3"), 1);
        for i in 0..3 {
            assert!(matches!(imp.offer(0, i, 10), Fate::Queued { .. }));
        }
        assert_eq!(imp.offer(0, 3, 10), Fate::Overflow);
        assert_eq!(imp.counts.overflow, 1);
        assert_eq!(imp.pop_due(999_999_999), None);
        assert_eq!(imp.pop_due(1_000_000_000), Some(0));
        assert!(matches!(imp.offer(0, 4, 10), Fate::Queued { .. }));
    }
}
