//! The one status message line: the app's, the stroke editor's and the practice panel's.

/// A status message under a panel's controls: `message` is its text and whether it reports
/// an error (then red). The app's message line, the stroke editor's and the practice panel's.
pub fn label(ui: &mut egui::Ui, message: &Option<(String, bool)>) {
    if let Some((m, error)) = message {
        let c = if *error {
            egui::Color32::from_rgb(230, 80, 70)
        } else {
            ui.visuals().text_color()
        };
        ui.label(egui::RichText::new(m).color(c));
    }
}
