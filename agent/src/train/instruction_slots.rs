//! The latest instruction's words, kept per env slot for the token's instruction slots
//! (`model.instruction_words` = K > 0; `model::instruction` says why; not in the paper).
//!
//! A row's slots are cleared when a new instruction phase begins (an instruction step after a
//! trial step, or an episode's first step) and every instruction step appends its word, so
//! during a trial they hold the sentence the agent was last told: after a success (no
//! re-instruction) the previous one, after a failure the new one. Past K words the oldest is
//! dropped (Meta-World's sentences have at most 12 words).

#[derive(Debug)]
pub struct InstructionSlots {
    slots: usize,
    word: usize,
    /// rows × K × (1 + W): per slot [valid, word…], filled from the front.
    values: Vec<f32>,
    filled: Vec<usize>,
    in_instruction: Vec<bool>,
}

impl InstructionSlots {
    pub fn new(rows: usize, slots: usize, word: usize) -> Self {
        Self {
            slots,
            word,
            values: vec![0.0; rows * slots * (1 + word)],
            filled: vec![0; rows],
            in_instruction: vec![false; rows],
        }
    }

    fn row_len(&self) -> usize {
        self.slots * (1 + self.word)
    }

    /// Takes one step of every row: its word `[rows × W]`, whether it is an instruction step,
    /// and whether it is an episode's first step.
    pub fn observe(&mut self, words: &[f32], instruction: &[bool], episode_start: &[bool]) {
        let (w, len) = (self.word, self.row_len());
        for r in 0..self.filled.len() {
            let row = &mut self.values[r * len..(r + 1) * len];
            let new_phase = instruction[r] && !self.in_instruction[r];
            if episode_start[r] || new_phase {
                row.fill(0.0);
                self.filled[r] = 0;
            }
            self.in_instruction[r] = instruction[r];
            if !instruction[r] {
                continue;
            }
            if self.filled[r] == self.slots {
                row.copy_within(1 + w.., 0);
                self.filled[r] -= 1;
            }
            let at = self.filled[r] * (1 + w);
            row[at] = 1.0;
            row[at + 1..at + 1 + w].copy_from_slice(&words[r * w..(r + 1) * w]);
            self.filled[r] += 1;
        }
    }

    /// Row `r`'s slots, K × (1 + W) values.
    pub fn row(&self, r: usize) -> &[f32] {
        let len = self.row_len();
        &self.values[r * len..(r + 1) * len]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Row 0's words in its valid slots.
    fn words(s: &InstructionSlots) -> Vec<f32> {
        s.row(0)
            .chunks(2)
            .filter(|slot| slot[0] == 1.0)
            .map(|slot| slot[1])
            .collect()
    }

    #[test]
    fn a_trial_sees_the_last_sentence_and_a_new_phase_replaces_it() {
        let mut s = InstructionSlots::new(1, 3, 1);
        s.observe(&[1.0], &[true], &[true]);
        s.observe(&[2.0], &[true], &[false]);
        assert_eq!(words(&s), vec![1.0, 2.0]);
        // Trial steps keep the sentence (their own word field is zeros).
        s.observe(&[0.0], &[false], &[false]);
        s.observe(&[0.0], &[false], &[false]);
        assert_eq!(words(&s), vec![1.0, 2.0]);
        // Re-instruction: a new phase starts from empty slots.
        s.observe(&[7.0], &[true], &[false]);
        assert_eq!(words(&s), vec![7.0]);
        // A new episode clears them even without an instruction step.
        s.observe(&[0.0], &[false], &[true]);
        assert_eq!(words(&s), Vec::<f32>::new());
        assert_eq!(s.row(0), &[0.0; 6]);
    }

    #[test]
    fn past_k_words_the_oldest_is_dropped_and_rows_are_independent() {
        let mut s = InstructionSlots::new(2, 2, 1);
        for (i, w) in [1.0, 2.0, 3.0].into_iter().enumerate() {
            s.observe(&[w, 10.0 + w], &[true, i == 0], &[i == 0, i == 0]);
        }
        assert_eq!(words(&s), vec![2.0, 3.0]);
        assert_eq!(s.row(1), &[1.0, 11.0, 0.0, 0.0]);
    }
}
