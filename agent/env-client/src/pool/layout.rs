//! Where each environment lives: groups of consecutive env indices, each group
//! split into contiguous blocks, one block (one handle) per server.
use std::ops::Range;

/// Splits `0..n` into `parts` contiguous ranges whose sizes differ by at most
/// one, larger ones first.
pub fn split_even(range: Range<usize>, parts: usize) -> Vec<Range<usize>> {
    let n = range.len();
    let (base, extra) = (n / parts, n % parts);
    let mut out = Vec::with_capacity(parts);
    let mut start = range.start;
    for p in 0..parts {
        let len = base + usize::from(p < extra);
        out.push(start..start + len);
        start += len;
    }
    out
}

/// One block: the envs `envs` of a group, placed on server number `server`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Block {
    pub server: usize,
    pub envs: Range<usize>,
}

/// Groups of `num_envs` over `servers` servers: group g's envs are consecutive,
/// and spread over the servers so each server carries an equal share of every
/// group (the groups step at different times, so every server stays busy).
pub fn layout(num_envs: usize, groups: usize, servers: usize) -> Vec<(Range<usize>, Vec<Block>)> {
    split_even(0..num_envs, groups)
        .into_iter()
        .enumerate()
        .map(|(g, group)| {
            let blocks = split_even(group.clone(), servers.min(group.len()))
                .into_iter()
                .enumerate()
                // Rotating the first server per group spreads odd remainders.
                .map(|(i, envs)| Block {
                    server: (i + g) % servers,
                    envs,
                })
                .collect();
            (group, blocks)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_env_is_placed_once_in_order() {
        for (n, g, s) in [(16, 1, 1), (16, 2, 2), (7, 3, 2), (5, 1, 8), (4, 4, 3)] {
            let l = layout(n, g, s);
            assert_eq!(l.len(), g);
            let mut next = 0;
            for (group, blocks) in &l {
                assert_eq!(group.start, next);
                for b in blocks {
                    assert_eq!(b.envs.start, next);
                    assert!(!b.envs.is_empty() && b.server < s);
                    next = b.envs.end;
                }
                assert_eq!(next, group.end);
                let mut servers: Vec<_> = blocks.iter().map(|b| b.server).collect();
                servers.sort_unstable();
                servers.dedup();
                assert_eq!(
                    servers.len(),
                    blocks.len(),
                    "one handle per server and group"
                );
            }
            assert_eq!(next, n);
        }
    }

    #[test]
    fn shares_are_balanced() {
        let l = layout(16, 2, 2);
        let sizes: Vec<usize> = l
            .iter()
            .flat_map(|(_, b)| b.iter().map(|b| b.envs.len()))
            .collect();
        assert_eq!(sizes, vec![4, 4, 4, 4]);
    }
}
