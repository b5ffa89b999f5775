use super::Pee;
pub fn go() {
    let _ = Pee;
}
