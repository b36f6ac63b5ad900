GET /app.js
